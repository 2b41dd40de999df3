"""A camera's health checker as the service, a replay and a zone apply build it: its
reference, the zone file's watch zones, and the model's envelope judged on the whole view and
on each protective zone's image region (docs/health.md)."""

from __future__ import annotations

import numpy as np

from monitor.detector.envelope import Envelope
from monitor.detector.inplace import InPlaceCheck
from monitor.health.camera import CameraHealth
from monitor.health.config import HealthConfig
from monitor.zones import Cell, watch_regions
from monitor.zones.masks import zone_regions_px


def camera_health(config: HealthConfig, camera_id: str, reference: np.ndarray | None,
                  cell: Cell | None, envelope: Envelope | None) -> CameraHealth:
    """The health checker of one camera for this zone set."""
    watch = watch_regions(cell, camera_id) if cell is not None else []
    protective = [(z.id, p) for z, p in zone_regions_px(cell, camera_id, ("protective",))] \
        if cell is not None else []
    return CameraHealth(config, camera_id, reference, watch, envelope, protective)


def protective_regions(cell: Cell | None, camera_ids: list[str]
                       ) -> dict[str, list[tuple[str, np.ndarray]]]:
    """Per camera, its protective zones' image regions (the in-place check's targets)."""
    if cell is None:
        return {}
    return {cid: [(z.id, p) for z, p in zone_regions_px(cell, cid, ("protective",))]
            for cid in camera_ids}


def inplace_check(detector, cell: Cell | None, camera_ids: list[str], period_s: float
                  ) -> InPlaceCheck | None:
    """The in-place detection check of every camera's protective zones, when the model has a
    self-test image to paste (None: it has not; docs/health.md)."""
    case = getattr(detector, "self_test_case", None)
    if case is None or cell is None:
        return None
    return InPlaceCheck(case, detector.detect, protective_regions(cell, camera_ids), period_s)
