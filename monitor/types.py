"""Plain data that flows between the pipeline stages.

Coordinates are named by their frame: ``*_px`` are pixels of one camera at its full resolution,
``*_m`` are metres in the cell frame. Times are seconds on the monotonic clock (or the video's own
clock in replay), never wall time, unless the name says ``wall``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class FrameInfo:
    """Where and when a frame was taken."""

    camera_id: str
    seq: int  # frame sequence number of this camera, starts at 0
    capture_time: float  # seconds, monotonic clock (video time in replay)
    width: int
    height: int


@dataclass(frozen=True)
class Persons:
    """The persons seen in one frame: parallel arrays, one row per person.

    ``boxes_px`` is (N, 4) float32 ``x1, y1, x2, y2`` in the frame's pixels; ``scores`` is (N,)
    float32 in [0, 1]. A person's id is its row index in this frame.
    """

    boxes_px: np.ndarray
    scores: np.ndarray
    frame: FrameInfo | None = None

    def __post_init__(self) -> None:
        boxes = np.asarray(self.boxes_px, dtype=np.float32).reshape(-1, 4)
        scores = np.asarray(self.scores, dtype=np.float32).reshape(-1)
        if len(boxes) != len(scores):
            raise ValueError(f"Persons: {len(boxes)} boxes but {len(scores)} scores")
        object.__setattr__(self, "boxes_px", boxes)
        object.__setattr__(self, "scores", scores)

    def __len__(self) -> int:
        return len(self.scores)

    @classmethod
    def empty(cls, frame: FrameInfo | None = None) -> Persons:
        return cls(np.zeros((0, 4), np.float32), np.zeros((0,), np.float32), frame)

    def __getitem__(self, index: np.ndarray | slice) -> Persons:
        """Mask or index rows; returns a new object."""
        return Persons(self.boxes_px[index], self.scores[index], self.frame)


@dataclass(frozen=True)
class ZoneHit:
    """One person inside (or overlapping) one zone."""

    zone_id: str
    kind: str  # "protective" or "warning"
    person: int  # row index in Persons
    speed_scale: float  # allowed speed fraction for warning zones; 0.0 for protective
    distance_m: float | None = None  # 0.0 when a volume overlaps; None for image zones
    track_id: int | None = None  # persistent person id across frames (None: not tracked)
    lost: bool = False  # held by a track lost inside the zone: not seen in this frame
    lost_since: float | None = None  # when that track was last seen (s, same clock as frames)
    # the person's id in the cell, as reasons name it (monitor.tracking.cell_persons): one id for
    # one person on every camera, "cam1:4" on an uncalibrated camera of several; None: track_id
    who: int | str | None = None
    note: str = ""  # a lost hit's own words (a hold handed over by another monitor)


@dataclass(frozen=True)
class ZoneReport:
    """Answer of the zone checks for one frame. Queries only: no timers, no state."""

    hits: tuple[ZoneHit, ...] = ()
    masked: tuple[int, ...] = ()  # persons ignored because anchored inside a mask zone
    tool_separation_m: float | None = None  # smallest person-to-tool distance, None if unknown
    required_separation_m: float | None = None  # ISO/TS 15066 protective separation S_p
    # largest fraction of the programmed robot speed that v_max(separation) allows
    # (ISO/TS 15066 closed form): 0.0 means STOP, None means separation not evaluated
    separation_speed_scale: float | None = None
    config_hash: str = ""


@dataclass(frozen=True)
class Fault:
    """A health problem. ``stop`` faults make the policy STOP; the others are warnings."""

    name: str  # e.g. "camera_lost", "camera_frozen", "detector_error", "pose_stale"
    reason: str
    stop: bool = True
    source: str = ""  # camera id, "pose", "detector", ...
    latch: bool = False  # latches the STOP even with restart_interlock "auto" (a stall)


@dataclass(frozen=True)
class Alert:
    """Something a person should look at; published on ``safety/alert``."""

    kind: str  # e.g. "scene_change", "camera_defocused", "pose_rejected"
    severity: str  # "info" | "warning" | "critical"
    message: str
    source: str
    time: float
    snapshot_jpeg: bytes | None = field(default=None, repr=False)
    details: dict = field(default_factory=dict)
