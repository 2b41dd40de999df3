"""What the health checks answer for one frame: ``HealthReport`` and each watch zone's
``ZoneStatus``."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from monitor.types import Alert, Fault


@dataclass(frozen=True)
class ZoneStatus:
    """State of one watch zone after a frame: "learning" (no background yet), "normal",
    "pending" (changed, not yet for ``persist_time_s``), "active" (alert raised) or "clearing"."""

    zone_id: str
    state: str
    changed_area_px: float = 0.0  # px² of the changed region in this frame
    box_px: tuple[int, int, int, int] | None = None  # x1, y1, x2, y2 of the change



@dataclass(frozen=True)
class HealthReport:
    """Answer of ``CameraHealth.check`` for one frame.

    ``faults`` are the faults active now (the policy STOPs on ``stop`` ones); ``alerts`` are the
    alerts this frame raised (events, each reported once). ``measures`` holds the raw numbers for
    the replay summary (brightness, contrast, saturated, frame_diff, sharpness_ratio, shift_px,
    match); ``timings_ms`` the cost of each check in milliseconds (keys in ``CHECKS`` and "total").
    """

    camera_id: str
    time: float
    faults: tuple[Fault, ...] = ()
    alerts: tuple[Alert, ...] = ()
    zones: tuple[ZoneStatus, ...] = ()
    measures: dict[str, float] = field(default_factory=dict)
    timings_ms: dict[str, float] = field(default_factory=dict)
    # this frame's picture really changed (as a live camera's does; not a repeat, nor a
    # codec's lone keyframe jump in a repeated picture): the pipeline dates what the frame
    # shows by the last frame that did (frame age, lost persons' times)
    picture_changed: bool = True
    # the frame's analysis image (BGR uint8, monitor/health/analysis.py) the checks judged:
    # the objects watch judges the same one instead of making its own (issue 49)
    analysis_bgr: np.ndarray | None = field(default=None, repr=False, compare=False)
