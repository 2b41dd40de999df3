"""The data of the pipeline's parts: what one step hands on (``StepResult``) and what the
pipeline remembers of each camera between steps (``CameraState``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from monitor.cases.muting import Mute, MuteOutcome
from monitor.health import CameraHealth, HealthReport
from monitor.pipeline.area_views import AreaView, UnseenView
from monitor.pipeline.pocket_views import PocketView
from monitor.policy import Command
from monitor.tracking.cell_persons import Who
from monitor.tracking.tracks import PersonTracker
from monitor.types import Alert, Fault, FrameInfo, Persons, ZoneReport
from monitor.wire.object_accepts import AcceptOutcome


@dataclass(frozen=True)
class StepResult:
    """What one processed frame (or one timer tick) produced."""

    now: float
    command: Command
    changed: bool  # the command differs from the previous step's (state, latch or reasons)
    frame: FrameInfo | None = None
    persons: Persons | None = None
    zone_report: ZoneReport | None = None
    health: HealthReport | None = None
    faults: tuple[Fault, ...] = ()
    alerts: tuple[Alert, ...] = ()
    stage_ms: dict[str, float] = field(default_factory=dict)  # stage -> wall ms (not replayed)
    track_ids: tuple[int, ...] = ()  # persistent person id per row of ``persons``
    masked_boxes: int = 0  # raw detector boxes suppressed by mask zones in this frame
    # mute requests judged since the previous step (the bus answers them), and the mutes
    # that hold at this decision (docs/muting.md)
    mute_outcomes: tuple[MuteOutcome, ...] = ()
    mutes: tuple[Mute, ...] = ()
    person_ids: tuple[Who, ...] = ()  # the cell person of each row (monitor.tracking.cell_persons)
    # operators' acceptances of objects since commissioning judged since the previous step
    # (the bus answers them; monitor.wire.object_accepts)
    accept_outcomes: tuple[AcceptOutcome, ...] = ()
    # where the lost persons could be, and what each camera cannot see, after this step (the
    # screen draws them: why the cell is held; monitor.pipeline.area_views)
    areas: tuple[AreaView, ...] = ()
    unseen: tuple[UnseenView, ...] = ()
    # the hidden pockets with their counts (monitor.pipeline.pocket_views): what ends a hold
    # behind a cabinet
    pockets: tuple[PocketView, ...] = ()


@dataclass
class CameraState:
    """What the pipeline remembers of one camera between steps."""

    health: CameraHealth | None = None
    # capture time of what its newest processed frame shows: the frame's own, or while the
    # picture repeats (a frozen camera, a codec's keyframe in it) that of the last frame whose
    # picture really changed (``HealthReport.picture_changed``)
    frame_time: float | None = None
    report: ZoneReport | None = None  # zone answer of that frame (None: unknown)
    faults: tuple[Fault, ...] = ()  # faults of that frame (health, detector, zones)
    detector_error: str | None = None
    tracker: PersonTracker | None = None
