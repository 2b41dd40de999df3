"""Camera integrity and scene-change checks: one small stateful checker per camera.

``CameraHealth.check(frame, now, person_boxes_px)`` looks at every frame of one camera and says
which health faults are active (lost, frozen, blinded, moved: the policy STOPs; defocused: a
warning) and which alerts this frame raised (a lasting change in a ``watch`` zone, with a JPEG
snapshot that outlines the change, and its clearing). "Lost" cannot be seen in a frame:
``check_lost(now)`` answers it between frames.

All checks run on a small copy of the frame (``analysis_width`` px wide, 320 by default; grey
for the camera checks, colour for the watch zones), so together they cost about 1 ms per 1080p
frame (``benchmarks/health.py``). Coordinates given to and returned by this package are pixels
of the camera's full-resolution frame (``*_px``). Times are seconds on the caller's clock
(monotonic, or the video's own clock in replay): ``now`` is passed in, never read here, so a
replay gives the same answers every time.

A reference image (taken at commissioning with ``monitor reference capture``) anchors three
checks: "moved" compares the view with it by phase correlation, "defocused" compares sharpness
(variance of the Laplacian) with it, and the watch zones start from it as their background.
Without a reference the first healthy frame without persons takes its place, so only changes
during this run are seen.

Modules: ``config`` (thresholds, fault and alert names), ``analysis`` (the one small copy of a
frame every image check judges, the objects watch too), ``report`` (what a check answers),
``camera`` (``CameraHealth``: the camera STOP faults and the defocus warning), ``scene`` (the
watch zones' scene changes) and ``draw`` (drawing a report; snapshot JPEGs). Import the names
below from ``monitor.health``.

Also here: which reference image a camera's checks start from, the zone file's or monitor.toml's
(``references.py``). May import: ``monitor.detector`` (image statistics, the envelope),
``monitor.zones`` (watch regions) and the layers under them; never the pipeline.
"""

from __future__ import annotations

from monitor.health.camera import CameraHealth, load_reference
from monitor.health.config import (
    BLINDED,
    CHECKS,
    DEFOCUSED,
    DEFOCUSED_CLEARED,
    FROZEN,
    LOST,
    MOVED,
    SCENE_CHANGE,
    SCENE_CHANGE_CLEARED,
    HealthConfig,
)
from monitor.health.draw import WATCH_BGR, draw_health
from monitor.health.report import HealthReport, ZoneStatus
from monitor.health.scene import WatchZones

__all__ = [
    "BLINDED",
    "CHECKS",
    "DEFOCUSED",
    "DEFOCUSED_CLEARED",
    "FROZEN",
    "LOST",
    "MOVED",
    "SCENE_CHANGE",
    "SCENE_CHANGE_CLEARED",
    "WATCH_BGR",
    "CameraHealth",
    "HealthConfig",
    "HealthReport",
    "WatchZones",
    "ZoneStatus",
    "draw_health",
    "load_reference",
]
