"""Mask zones never hide a person: the rule that suppresses boxes, applied before merging.

A mask zone covers something person-like that never moves (a poster, a mannequin, a cut-out).
The old rule ignored every *merged* person whose anchor fell in a mask: a real person just
behind a masked cut-out merged with it into one box, the anchor landed in the mask, and the
person vanished. The rule here:

* a raw detector box is suppressed only when the **whole box** lies inside a mask zone's image
  region (an image polygon, or the outline of a mask volume seen through the camera's
  calibration), the region grown by the detector's box error (``margin_px``, about one grid
  cell of the model) so a tight mask still suppresses its own cut-out;
* a box reaching out of the region by more than that is kept;
* it runs on the raw boxes **before** NMS and merging (``Detector.detect_timed(...,
  pre_merge=rule.keep)``), so a suppressed look-alike never joins a real person's box.

``mask_warnings`` lists masks drawn close to a protective or warning zone, for ``zones
validate``: a person standing there may be hidden by the mask.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from monitor.zones.draw import _volume_region_px
from monitor.zones.files import Cell
from monitor.zones.schema import PolygonZone

ALERT_KINDS = ("protective", "warning")


def zone_regions_px(cell: Cell, camera_id: str, kinds: tuple[str, ...]
                    ) -> list[tuple[Any, np.ndarray]]:
    """Enabled zones of ``kinds`` as seen by one camera: (zone, polygon (K, 2) float32 px).
    Volume zones are the convex hull of their projection (cameras with a calibration)."""
    cam = cell.cameras.get(camera_id)
    model = cell.camera_models.get(camera_id)
    out: list[tuple[Any, np.ndarray]] = []
    if cam is None:
        return out
    for z in cell.zones:
        if z.kind not in kinds or not z.enabled:
            continue
        if isinstance(z, PolygonZone):
            if z.camera == camera_id:
                out.append((z, np.array(z.points_px, np.float32)))
        elif model is not None:
            region = _volume_region_px(z, cell, model, cam)
            if region is not None:
                out.append((z, np.asarray(region, np.float32)))
    return out


def _raster(polygons: list[np.ndarray], width: int, height: int) -> np.ndarray:
    img = np.zeros((height, width), np.uint8)
    for p in polygons:
        cv2.fillPoly(img, [np.round(p).astype(np.int32).reshape(-1, 1, 2)], 1)
    return img


def _grow(img: np.ndarray, margin_px: float) -> np.ndarray:
    r = int(np.ceil(max(margin_px, 0.0)))
    if r == 0:
        return img
    return cv2.dilate(img, cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1)))


class MaskRule:
    """Which raw boxes a camera's mask zones suppress: boxes wholly inside the grown masks.

    ``keep(boxes_px)`` is True for every box to keep. Containment is exact to the pixel and
    conservative: a box covers every pixel it touches, so a box that reaches a pixel outside
    the grown mask is kept. One summed-area lookup per box.
    """

    def __init__(self, polygons: list[np.ndarray], width: int, height: int,
                 margin_px: float) -> None:
        self.width, self.height = int(width), int(height)
        self.margin_px = float(margin_px)
        self.polygons = [np.asarray(p, np.float32).reshape(-1, 2) for p in polygons]
        self.active = bool(self.polygons)
        grown = _grow(_raster(self.polygons, self.width, self.height), self.margin_px)
        self._sum = cv2.integral(grown, sdepth=cv2.CV_64F)

    @classmethod
    def for_camera(cls, cell: Cell, camera_id: str, width: int, height: int,
                   margin_px: float) -> MaskRule:
        """The rule of ``camera_id``'s mask zones at frame size ``width`` x ``height`` (zone
        pixels are at the camera's full resolution: scaled when the frame differs)."""
        cam = cell.cameras.get(camera_id)
        polys = [p for _, p in zone_regions_px(cell, camera_id, ("mask",))]
        if cam is not None and (cam.width, cam.height) != (width, height):
            sx, sy = width / cam.width, height / cam.height
            polys = [p * np.array([sx, sy], np.float32) for p in polys]
        return cls(polys, width, height, margin_px)

    def keep(self, boxes_px: np.ndarray) -> np.ndarray:
        boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
        keep = np.ones(len(boxes), bool)
        if not self.active or not len(boxes):
            return keep
        finite = np.isfinite(boxes).all(axis=1)
        b = np.where(finite[:, None], boxes, 0.0)
        x1 = np.clip(np.floor(b[:, 0]), 0, self.width).astype(np.int64)
        y1 = np.clip(np.floor(b[:, 1]), 0, self.height).astype(np.int64)
        x2 = np.clip(np.ceil(b[:, 2]), 0, self.width).astype(np.int64)
        y2 = np.clip(np.ceil(b[:, 3]), 0, self.height).astype(np.int64)
        s = self._sum
        covered = s[y2, x2] - s[y1, x2] - s[y2, x1] + s[y1, x1]
        pixels = (x2 - x1) * (y2 - y1)
        inside = finite & (pixels > 0) & (covered >= pixels)
        return ~inside


def mask_warnings(cell: Cell, person_width_px: float | None = None) -> list[str]:
    """One line per mask zone that touches or comes within one person width of a protective
    or warning zone in some camera's image (``person_width_px``; default: a tenth of the
    image width, a person's box seen from a few metres). A person standing there can be hidden
    by the mask. Volume zones are compared through their image outlines in every calibrated
    camera."""
    out: list[str] = []
    seen: set[tuple[str, str]] = set()
    for camera_id, cam in cell.cameras.items():
        masks = zone_regions_px(cell, camera_id, ("mask",))
        if not masks:
            continue
        alerts = zone_regions_px(cell, camera_id, ALERT_KINDS)
        width = person_width_px if person_width_px is not None else cam.width / 10
        for mz, mpoly in masks:
            grown = _grow(_raster([mpoly], cam.width, cam.height), width)
            for az, apoly in alerts:
                if (mz.id, az.id) in seen:
                    continue
                if (grown & _raster([apoly], cam.width, cam.height)).any():
                    seen.add((mz.id, az.id))
                    out.append(f"mask zone '{mz.id}' is within a person's width "
                               f"of {az.kind} zone '{az.id}' in camera '{camera_id}': a person "
                               "there may be hidden; draw the mask tight around the object")
    return out
