"""Mask zones never hide a person: the rule that suppresses boxes, applied before merging.

A mask zone covers something person-like that never moves (a poster, a mannequin, a cut-out).
The old rule ignored every *merged* person whose anchor fell in a mask: a real person just
behind a masked cut-out merged with it into one box, the anchor landed in the mask, and the
person vanished. The rule here:

* raw detector boxes are grouped as merging would join them (touching or overlapping);
* a group lying wholly inside a mask zone's image region (an image polygon, or the outline of
  a mask volume through the camera's calibration), grown by the detector's box error
  (``margin_px``, about one grid cell), is suppressed only when its union **is the masked
  object's extent**: every edge within ``margin_px`` of the region's bounding box. A person
  in a mask drawn looser than its object, beside the object or in front of it looking larger,
  is kept; a mask looser than its object by more than the box error suppresses nothing;
* a group reaching out of the grown region (a person touching the object) loses its boxes
  wholly inside it (else the merged box would be placed at the object's feet), and its whole
  box is reported in ``MaskCheck.touching``: the pipeline checks it as a person too, since the
  person may reach into the mask (the worse answer counts);
* it runs on the raw boxes **before** NMS and merging (``Detector.detect_timed(...,
  pre_merge=...)``, see ``Pipeline._pre_merge``), so a suppressed look-alike never joins a
  real person's box.

See docs/masks.md for what this protects against and what it cannot.

``monitor.zones.mask_risk`` grades each mask for ``zones validate`` by what a person standing
there would look like.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from monitor.geometry.boxes import connected_groups, gap_matrix
from monitor.zones.draw import volume_region_px
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
            region = volume_region_px(z, cell, model, cam)
            if region is not None:
                out.append((z, np.asarray(region, np.float32)))
    return out


def raster(polygons: list[np.ndarray], width: int, height: int) -> np.ndarray:
    img = np.zeros((height, width), np.uint8)
    for p in polygons:
        cv2.fillPoly(img, [np.round(p).astype(np.int32).reshape(-1, 1, 2)], 1)
    return img


def grow_mask(img: np.ndarray, margin_px: float) -> np.ndarray:
    r = int(np.ceil(max(margin_px, 0.0)))
    if r == 0:
        return img
    return cv2.dilate(img, cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1)))


class MaskRule:
    """Which raw boxes a camera's mask zones suppress: a group of touching boxes that lies
    wholly inside a grown mask **and is the masked object's own extent**.

    ``keep(boxes_px)`` is True for every box to keep. Raw boxes are grouped as merging would
    join them (overlapping or touching within ``touch_px``). A group is suppressed only when

    * every box of it lies inside one mask's region grown by ``margin_px`` (containment exact
      to the pixel and conservative: a box covers every pixel it touches), and
    * the union of the group matches that mask's extent (the bounding box of its region) on
      every edge within ``margin_px``: the detector saw something exactly as large as, and
      exactly where, the masked object is.

    A group reaching out of the mask (a person touching the object) loses its boxes inside the
    mask and its whole box goes to ``MaskCheck.touching``. Anything else keeps the whole
    group: a person in a mask drawn looser than its object (the group is smaller than
    the mask's extent or placed elsewhere in it), a person in front of the object who looks
    larger than it. A mask drawn looser than its object by more than ``margin_px`` on any side
    therefore suppresses nothing: its object is reported as a person (a nuisance, never a
    miss). See docs/masks.md.
    """

    def __init__(self, polygons: list[np.ndarray], width: int, height: int,
                 margin_px: float, ids: tuple[str, ...] | None = None,
                 touch_px: float = 2.0) -> None:
        self.width, self.height = int(width), int(height)
        self.margin_px = float(margin_px)
        self.touch_px = float(touch_px)
        self.polygons = [np.asarray(p, np.float32).reshape(-1, 2) for p in polygons]
        self.ids = tuple(ids) if ids is not None else tuple(
            f"mask{i}" for i in range(len(self.polygons)))
        self.active = bool(self.polygons)
        self._sums = [cv2.integral(grow_mask(raster([p], self.width, self.height), self.margin_px),
                                   sdepth=cv2.CV_64F) for p in self.polygons]
        limits = np.array([self.width, self.height, self.width, self.height], np.float64)
        self.extents = np.array(
            [np.clip([*p.min(axis=0), *p.max(axis=0)], 0, limits) for p in self.polygons],
            np.float64).reshape(-1, 4)

    @classmethod
    def for_camera(cls, cell: Cell, camera_id: str, width: int, height: int,
                   margin_px: float) -> MaskRule:
        """The rule of ``camera_id``'s mask zones at frame size ``width`` x ``height`` (zone
        pixels are at the camera's full resolution: scaled when the frame differs)."""
        cam = cell.cameras.get(camera_id)
        regions = zone_regions_px(cell, camera_id, ("mask",))
        polys = [p for _, p in regions]
        if cam is not None and (cam.width, cam.height) != (width, height):
            sx, sy = width / cam.width, height / cam.height
            polys = [p * np.array([sx, sy], np.float32) for p in polys]
        return cls(polys, width, height, margin_px, tuple(z.id for z, _ in regions))

    def _inside(self, boxes: np.ndarray) -> np.ndarray:
        """(M, N) bool: box n lies wholly inside mask m's grown region."""
        finite = np.isfinite(boxes).all(axis=1)
        b = np.where(finite[:, None], boxes, 0.0)
        x1 = np.clip(np.floor(b[:, 0]), 0, self.width).astype(np.int64)
        y1 = np.clip(np.floor(b[:, 1]), 0, self.height).astype(np.int64)
        x2 = np.clip(np.ceil(b[:, 2]), 0, self.width).astype(np.int64)
        y2 = np.clip(np.ceil(b[:, 3]), 0, self.height).astype(np.int64)
        pixels = (x2 - x1) * (y2 - y1)
        out = np.zeros((len(self._sums), len(boxes)), bool)
        for m, s in enumerate(self._sums):
            covered = s[y2, x2] - s[y1, x2] - s[y2, x1] + s[y1, x1]
            out[m] = finite & (pixels > 0) & (covered >= pixels)
        return out

    def check(self, boxes_px: np.ndarray) -> MaskCheck:
        """Keep flags per raw box, and the masks that held a group they did not suppress."""
        boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
        keep = np.ones(len(boxes), bool)
        if not self.active or not len(boxes):
            return MaskCheck(keep)
        inside = self._inside(boxes)
        candidates = np.flatnonzero(inside.any(axis=0))
        if not len(candidates):
            return MaskCheck(keep)
        finite = np.isfinite(boxes).all(axis=1)
        safe = np.where(finite[:, None], boxes, 0.0)
        labels = connected_groups(gap_matrix(safe, safe) <= self.touch_px)
        limits = np.array([self.width, self.height, self.width, self.height], np.float64)
        unmatched: list[str] = []
        touching: list[np.ndarray] = []
        for g in np.unique(labels[candidates]):
            members = labels == g
            union = np.clip([safe[members, 0].min(), safe[members, 1].min(),
                             safe[members, 2].max(), safe[members, 3].max()], 0, limits)
            whole = inside[:, members].all(axis=1)  # masks holding the whole group
            if not whole.any():
                # a person touching the object: the boxes inside the mask go (else the merged
                # box would be placed at the object's feet), the rest of the group stays; the
                # whole group's box is reported too, as the person may reach into the mask
                keep[members & inside.any(axis=0)] = False
                touching.append(union)
                continue
            match = whole & (np.abs(self.extents - union).max(axis=1) <= self.margin_px)
            if match.any():
                keep[members] = False
            else:
                unmatched.extend(self.ids[m] for m in np.flatnonzero(whole))
        return MaskCheck(keep, tuple(dict.fromkeys(unmatched)),
                         np.array(touching, np.float64).reshape(-1, 4))

    def keep(self, boxes_px: np.ndarray) -> np.ndarray:
        return self.check(boxes_px).keep


@dataclass(frozen=True)
class MaskCheck:
    """One frame's mask answer: ``keep`` per raw box; ``unmatched``: masks that wholly held a
    group of boxes unlike their object (kept: a person, or a mask looser than its object);
    ``touching``: (K, 4) the whole box of each group that reached out of a mask and lost its
    boxes inside it (a person touching the object, who may reach into the mask: the pipeline
    checks this box as a person too, beside the part outside the mask)."""

    keep: np.ndarray
    unmatched: tuple[str, ...] = ()
    touching: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float64))
