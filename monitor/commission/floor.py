"""The floor of each protective and warning volume zone as a grid of cells, and which cells
some camera can see a person in (``monitor.zones.visibility.hidden_feet``, the map a lost
person's area is judged by).

A cell is *visible* when at least one calibrated camera has its centre in the image (in front
of it) and ``hidden_feet`` does not hide it there: a person of the minimum height standing on it
shows their head or waist past every occluder and the robot base, and the spot is in no mask
zone. A zone cell no camera sees is a *blind spot*: a person standing there cannot cause a STOP.
Floor inside an occluder's footprint is no cell (nobody stands in a bench). Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from monitor.geometry.occlusion import points_in_volume, standable
from monitor.zones import BoxZone, Cell, ExtrudeZone, volume_outline_m
from monitor.zones.masks import zone_regions_px
from monitor.zones.visibility import hidden_feet
from monitor.zones.volumes import box_corners

CELL_M = 0.25  # floor cell size of the walk test (a foot print, about)
ALARM_KINDS = ("protective", "warning")


@dataclass(frozen=True)
class ZoneFloor:
    """One zone's floor cells: centres (K, 2) metres, the cell size, the grid's origin and
    shape (cells of a zone are ``(row, col)`` indices of that grid), and which cells some
    camera sees (``visible``, (K,) bool)."""

    zone_id: str
    kind: str
    cell_m: float
    origin_m: tuple[float, float]
    shape: tuple[int, int]  # rows (y), cols (x)
    index: np.ndarray  # (K, 2) int: row, col
    centres_m: np.ndarray  # (K, 2)
    visible: np.ndarray  # (K,) bool
    # the corners of the zone's floor outline (a box's four, a polygon's points; none for a
    # cylinder or mesh): where the walk test has the integrator crouch
    corners_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    def cell_of(self, xy_m: np.ndarray) -> np.ndarray:
        """(N,) index into the zone's cells of each floor point; -1 outside the zone."""
        p = np.asarray(xy_m, float).reshape(-1, 2)
        out = np.full(len(p), -1, dtype=int)
        if not len(p) or not len(self.index):
            return out
        col = np.floor((p[:, 0] - self.origin_m[0]) / self.cell_m).astype(int)
        row = np.floor((p[:, 1] - self.origin_m[1]) / self.cell_m).astype(int)
        lookup = {(int(r), int(c)): k for k, (r, c) in enumerate(self.index)}
        for i, key in enumerate(zip(row.tolist(), col.tolist(), strict=True)):
            out[i] = lookup.get(key, -1)
        return out


def zone_floors(cell: Cell, cell_m: float = CELL_M) -> list[ZoneFloor]:
    """The floor grid of every enabled protective and warning volume zone (file order).
    Image-polygon zones have no floor: they are left out (the walk reports their entries)."""
    out = []
    occluders = cell.spec.occluder_zones()
    for z in cell.zones:
        if not (z.enabled and z.kind in ALARM_KINDS and z.is_volume):
            continue
        lines = np.concatenate(volume_outline_m(z, cell))
        lo, hi = lines[:, :2].min(axis=0), lines[:, :2].max(axis=0)
        cols = max(1, math.ceil((hi[0] - lo[0]) / cell_m - 1e-9))
        rows = max(1, math.ceil((hi[1] - lo[1]) / cell_m - 1e-9))
        rr, cc = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
        index = np.c_[rr.ravel(), cc.ravel()]
        centres = np.c_[lo[0] + (index[:, 1] + 0.5) * cell_m, lo[1] + (index[:, 0] + 0.5) * cell_m]
        z_mid = float((lines[:, 2].min() + lines[:, 2].max()) / 2)
        keep = points_in_volume(z, np.c_[centres, np.full(len(centres), z_mid)], cell.meshes)
        keep &= standable(occluders, cell.meshes, centres)
        index, centres = index[keep], centres[keep]
        out.append(ZoneFloor(z.id, z.kind, cell_m, (float(lo[0]), float(lo[1])), (rows, cols),
                             index, centres, visible_cells(cell, centres), corners_of(z)))
    return out


def corners_of(z) -> np.ndarray:
    """(C, 2) metres: the floor corners of a box or extruded polygon zone; none otherwise."""
    if isinstance(z, BoxZone):
        return np.asarray(box_corners(z), float)[:4, :2]
    if isinstance(z, ExtrudeZone):
        return np.asarray(z.points_m, float).reshape(-1, 2)
    return np.zeros((0, 2))


def visible_cells(cell: Cell, centres_m: np.ndarray) -> np.ndarray:
    """(K,) bool: some calibrated camera sees a person standing on each floor point."""
    pts = np.asarray(centres_m, float).reshape(-1, 2)
    seen = np.zeros(len(pts), dtype=bool)
    for camera_id, model in cell.camera_models.items():
        cam = cell.cameras[camera_id]
        px, front = model.project(np.c_[pts, np.zeros(len(pts))])
        px = px * np.array([cam.width / model.width, cam.height / model.height])
        inside = front & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) \
            & (px[:, 1] < cam.height)
        if not inside.any():
            continue
        masks = [p for _, p in zone_regions_px(cell, camera_id, ("mask",))]
        hidden = hidden_feet(px[inside], (cam.width, cam.height), model, cell.spec,
                             cell.meshes, masks)
        now = np.zeros(len(pts), dtype=bool)
        now[np.flatnonzero(inside)[~hidden]] = True
        seen |= now
    return seen


def feet_on_floor(cell: Cell, camera_id: str, boxes_px: np.ndarray, width: int, height: int
                  ) -> np.ndarray:
    """(M, 2) floor points under the bottom centre of each box (boxes the camera cannot place
    on the floor are left out; an uncalibrated camera places none)."""
    model = cell.camera_models.get(camera_id)
    boxes = np.asarray(boxes_px, float).reshape(-1, 4)
    if model is None or not len(boxes):
        return np.zeros((0, 2))
    feet = np.c_[(boxes[:, 0] + boxes[:, 2]) / 2, boxes[:, 3]]
    feet = feet * np.array([model.width / width, model.height / height])
    xy, ok = model.pixel_to_floor(feet)
    return np.asarray(xy, float)[ok]
