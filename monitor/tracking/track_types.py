"""What the person tracker hands out (``monitor.tracking.tracks``): its settings, a track's
snapshot, a hold (a lost person whose area touches zones) and what one frame did to the tracks;
the calibration and hidden-cell callables it is given."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from monitor.timetext import TimeText
from monitor.tracking.whereabouts import FootGrid, HeldZone, WhereaboutsConfig
from monitor.types import ZoneReport

# pixels (N, 2) -> (floor xy metres (N, 2), located (N,) bool): a camera's calibration
ToFloor = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
# the camera's hidden foot cells (monitor.zones.visibility) for a grid of its image
HiddenCells = Callable[[FootGrid], np.ndarray]


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of the person tracker (defaults suit 10-30 fps cameras)."""

    # seconds (not frames) ByteTrack keeps a lost track for re-association: turned into
    # frames at the measured frame rate, so 2 fps keeps a track as long as 30 fps does
    lost_track_s: float = 1.0
    matching_threshold: float = 0.8  # ByteTrack's association cost limit (1 - IoU, fused)
    near_factor: float = 1.0  # a new person within this many box widths re-finds a lost one
    # a person walks this fast at most (m/s): a track unseen for dt seconds is re-found within
    # walk_speed_mps * dt of its last box (measured in box heights of a height_m person), so
    # ids survive low frame rates; a track that holds a zone is never re-found this way (the
    # new person is said as "person 6 (was person 1?)"); the lost persons' areas grow at this
    # speed too
    walk_speed_mps: float = 1.5
    height_m: float = 1.75
    reach_max_s: float = 2.0  # ids: no further than this many seconds of walking
    edge_margin_px: float = 8.0  # a box this close to the image border is "at the edge"
    exit_speed_pxps: float = 5.0  # outward speed at the edge that counts as leaving the view
    forget_after_s: float = 60.0  # lost tracks without an area are forgotten after this long
    velocity_smoothing: float = 0.5  # weight of the newest velocity sample (0..1]
    # a lost track's last box this much inside a seen box was merged into it: where both
    # stood is kept (someone may be hidden in the merged box) until seen free
    merge_ios: float = 0.3
    # where a lost person could be (monitor.tracking.whereabouts): grid columns over the image, the
    # reach's perspective margin, the share of a box under it where hidden feet may be
    cells_across: int = 48
    reach_margin: float = 1.5
    below: float = 0.25

    def areas(self) -> WhereaboutsConfig:
        return WhereaboutsConfig(self.cells_across, self.walk_speed_mps, self.height_m,
                                 self.reach_margin, self.below)


@dataclass(frozen=True)
class Track:
    """One person's track as of the newest update (a snapshot; the tracker keeps its own)."""

    track_id: int
    box_px: tuple[float, float, float, float]  # last seen box
    last_seen: float  # capture time of the last frame the person was seen in
    velocity_pxps: tuple[float, float]  # image velocity of the box centre
    floor_m: tuple[float, float] | None = None  # bottom-centre on the floor (calibrated camera)
    floor_velocity_mps: tuple[float, float] | None = None
    zones: tuple[HeldZone, ...] = ()  # protective/warning zones hit at the last sighting
    lost: bool = False
    held: tuple[HeldZone, ...] = ()  # zones this lost track keeps occupied
    was: int | None = None  # perhaps this lost person, re-identified by a guess
    left_view: bool = False  # lost at an image edge moving outwards (handed over to peers)


@dataclass(frozen=True)
class Hold:
    """A lost person whose area (where they could be) touches zones. ``seen_as``: a person
    seen since near where this one was lost, perhaps the same (a guess: the hold stays until
    the zones are seen free or an operator confirms the cell clear)."""

    track_id: int
    zones: tuple[HeldZone, ...]
    lost_since: float
    box_px: tuple[float, float, float, float]
    seen_as: int | str | None = None
    # the cell person (monitor.tracking.cell_persons); None: the track id
    who: int | str | None = None

    def describe(self, when: TimeText | None = None) -> str:
        """``person 3 lost inside stop``, with ``at <when(lost_since)>`` when a clock is given
        (a log line carries its own time)."""
        names = ", ".join(z.zone_id for z in self.zones)
        at = "" if when is None else f" at {when(self.lost_since)}"
        maybe = "" if self.seen_as is None else f" (seen again as person {self.seen_as}?)"
        who = self.track_id if self.who is None else self.who
        return f"person {who} lost inside {names}{at}{maybe}"


@dataclass(frozen=True)
class TrackUpdate:
    """What one frame did to the tracks."""

    track_ids: tuple[int, ...]  # per row of the frame's Persons
    report: ZoneReport | None  # the zone report with track ids and the holds' lost hits
    started: tuple[Hold, ...] = ()  # holds that began in this frame
    ended: tuple[Hold, ...] = ()  # holds ended in this frame (their zones were seen free)
    # (new id, lost id): a new person near a lost one that holds a zone, perhaps the same
    reidentified: tuple[tuple[int, int], ...] = ()
    # (track id, rule) of every lost person's area that ended in this frame: "seen free",
    # "seen again", "under seen persons", "bounded life" (monitor.tracking.whereabouts)
    ended_by: tuple[tuple[int, str], ...] = ()


def lost_person_index(track_id: int) -> int:
    """The ``ZoneHit.person`` of a lost person's hit: negative (no row in this frame's
    ``Persons``) and distinct per track, so merging reports keeps every hold."""
    return -1 - track_id
