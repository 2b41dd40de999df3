"""A hidden person is still a person: where on the floor a box may stand, and what cameras miss.

Pure functions, no state. Coordinates: ``*_px`` raw pixels of one camera at full resolution,
``*_m`` cell metres (z up, floor at z = 0).

**Placement.** A person box gives a *range* of floor positions along the camera's viewing
direction, from ``near_m`` (nearer the camera) to ``far_m``:

* feet visible: the feet lie between ``band_hi_px`` and ``band_lo_px`` above the box's bottom
  edge (the detector's measured box-bottom error; the synthetic model's cell-aligned boxes reach
  0..1 grid cell below the feet, a trained export's are tighter);
* feet may be hidden (the box bottom lies on the image outline of a known occluder, or on the
  image edge, or the box is shorter than a person of ``height_range_m[0]`` standing where its
  bottom says): the head (box top) is placed on every height in ``height_range_m`` and the feet
  may be anywhere from under the lowest head to under the highest, but never farther than the
  visible bottom allows.

The zone check then tests the person cylinder swept along that segment (a stadium on the floor,
extruded to the person height), so every position the evidence allows is tested: a person behind
a bench is found in the protective zone even though the box bottom lies on the bench top.

**Shadows.** A floor point is in a camera's *shadow* when a person of the minimum height
(``height_range_m[0]``) standing there would be wholly hidden from that camera: the sight line
from the camera to the top of their head passes through an occluder, or that head is outside the
image or behind the camera. Persons whose head shows are placed from the head (above); persons in
a shadow of every camera cannot be seen at all, and ``zones validate`` warns about zone floor
that lies there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from monitor import geometry as geo

# How close (pixels) a box bottom must come to an occluder outline or the image edge for the
# feet to count as possibly hidden, besides the detector's foot band.
EDGE_TOLERANCE_PX = 3.0
# Synthetic model (tiny-YOLOv3 layout, 416 input): box bottom minus true feet, measured on the
# demo scene and random frames (123 persons in clear view, benchmarks/scenarios.py): 0.8 .. 49.4
# px at 1280x720 where one grid cell is 49.2 px, i.e. 0 .. 1 cell, median 0.43 cell.
SYNTHETIC_FOOT_BAND_CELLS = (0.0, 1.0)


@dataclass(frozen=True)
class Placement:
    """Floor positions a frame's persons may stand on (parallel arrays, one row per box).

    ``near_m``/``far_m`` (N, 2): ends of the segment of possible feet positions (equal when the
    answer is a point). ``located`` (N,): False when the box cannot be put on the floor at all
    (its feet range reaches the horizon): such a person must count as everywhere.
    ``hidden`` (N,): the feet may be hidden, the range comes from the head. ``feet_top_px`` and
    ``feet_bottom_px`` (N,): image rows between which the feet may be (for image zones with the
    bottom-centre anchor); ``feet_u_px`` (N,) the column.
    """

    near_m: np.ndarray
    far_m: np.ndarray
    located: np.ndarray
    hidden: np.ndarray
    feet_u_px: np.ndarray
    feet_top_px: np.ndarray
    feet_bottom_px: np.ndarray

    @property
    def length_m(self) -> np.ndarray:
        return np.hypot(*(self.far_m - self.near_m).T)


def camera_centre_m(model: geo.CameraModel) -> np.ndarray | None:
    """Camera centre in the cell frame, or None for a homography-only calibration."""
    if model.rotation is None or model.translation_m is None:
        return None
    return -model.rotation.T @ model.translation_m


def pixel_rays(model: geo.CameraModel, px: np.ndarray) -> np.ndarray:
    """Unit viewing directions (N, 3) in the cell frame of raw pixels (pinhole cameras only)."""
    und = model.undistort_px(px)
    k = model.camera_matrix
    d_cam = np.c_[(und[:, 0] - k[0, 2]) / k[0, 0], (und[:, 1] - k[1, 2]) / k[1, 1],
                  np.ones(len(und))]
    d = d_cam @ model.rotation  # R^T d_cam, row-wise
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def feet_may_be_hidden(boxes_px: np.ndarray, model: geo.CameraModel | None, width: int,
                       height: int, occluder_outlines_px: Sequence[np.ndarray] = (),
                       min_height_m: float = 1.0, band_hi_px: float = 0.0) -> np.ndarray:
    """(N,) bool: the feet of each box may be hidden, by the image edge, an occluder, or
    because the box is shorter than a person of ``min_height_m`` at the floor point its bottom
    implies (a pinhole calibration is needed for the last two)."""
    boxes = np.asarray(boxes_px, float).reshape(-1, 4)
    tol = EDGE_TOLERANCE_PX
    hidden = boxes[:, 3] >= height - tol
    if not len(boxes):
        return hidden
    u = (boxes[:, 0] + boxes[:, 2]) * 0.5
    reach = max(tol, band_hi_px)
    for outline in occluder_outlines_px:
        poly = np.asarray(outline, np.float32).reshape(-1, 1, 2)
        for i in np.flatnonzero(~hidden):
            # the visible bottom sits on (or just above, by the box error) the occluder's outline
            for y in (boxes[i, 3], boxes[i, 3] + reach):
                if cv2.pointPolygonTest(poly, (float(u[i]), float(y)), True) >= -tol:
                    hidden[i] = True
                    break
    if model is not None and model.can_project_3d:
        floor, ok = model.pixel_to_floor(np.c_[u, boxes[:, 3]])
        pts = np.r_[np.c_[floor, np.zeros(len(u))], np.c_[floor, np.full(len(u), min_height_m)]]
        px, front = model.project(pts)
        n = len(u)
        expected = px[:n, 1] - px[n:, 1]
        short = ok & front[:n] & front[n:] & (boxes[:, 3] - boxes[:, 1] < expected)
        hidden |= short
    return hidden


def place_persons(boxes_px: np.ndarray, model: geo.CameraModel, width: int, height: int, *,
                  band_px: tuple[float, float] = (0.0, 0.0),
                  height_range_m: tuple[float, float] = (1.0, 2.0),
                  occluder_outlines_px: Sequence[np.ndarray] = ()) -> Placement:
    """Where each box's person may stand (see the module docstring).

    ``band_px`` = (lo, hi): the feet lie ``lo`` .. ``hi`` pixels above the box's bottom edge.
    """
    boxes = np.asarray(boxes_px, float).reshape(-1, 4)
    n = len(boxes)
    lo, hi = float(band_px[0]), float(max(band_px))
    u = (boxes[:, 0] + boxes[:, 2]) * 0.5
    y_far = np.maximum(boxes[:, 3] - hi, boxes[:, 1] + 1.0)
    y_near = np.maximum(boxes[:, 3] - lo, y_far)
    both, ok = model.pixel_to_floor(np.r_[np.c_[u, y_far], np.c_[u, y_near]])
    far, near = both[:n].copy(), both[n:].copy()
    located = ok[:n] & ok[n:]
    bottom_px = y_near.copy()
    hidden = feet_may_be_hidden(boxes, model, width, height, occluder_outlines_px,
                                height_range_m[0], hi)
    centre = camera_centre_m(model)
    todo = np.flatnonzero(hidden)
    if centre is None or not len(todo):
        return Placement(near, far, located, hidden, u, y_far, bottom_px)
    h_min, h_max = height_range_m
    c_xy = centre[:2]
    # the head is at the box top, or up to the band lower (a box may reach above the head too)
    heads = np.r_[np.c_[u[todo], boxes[todo, 1]], np.c_[u[todo], boxes[todo, 1] + hi]]
    rays = pixel_rays(model, heads)
    m = len(todo)
    for j, i in enumerate(todo.tolist()):
        cands = []  # floor points under the head at each end of the height range
        unbounded = False  # a level or rising sight line: the head may be arbitrarily far
        for d in (rays[j], rays[m + j]):
            if d[2] > -1e-9 and h_max > centre[2]:
                unbounded = True
            if abs(d[2]) < 1e-9:
                continue
            for h in (h_min, h_max):
                s = (h - centre[2]) / d[2]
                if s > 0:
                    cands.append(centre[:2] + s * d[:2])
        if unbounded and not located[i]:
            continue  # neither the head nor the feet bound it: stays unplaceable (everywhere)
        if not cands and not unbounded:
            continue  # no height in the range fits the head: keep the feet-based answer
        dist = [float(np.hypot(*(p - c_xy))) for p in cands]
        head_near = cands[int(np.argmin(dist))] if cands else c_xy.copy()
        d_near = min(dist) if cands else 0.0
        d_vis = float(np.hypot(*(far[i] - c_xy))) if located[i] else np.inf
        d_far = np.inf if unbounded else max(dist)
        head_far = far[i] if unbounded else cands[int(np.argmax(dist))]
        # the feet are hidden below the visible bottom: never farther than it allows
        if d_far <= d_vis:
            new_near, new_far = head_near, head_far
        elif d_near <= d_vis:
            new_near, new_far = head_near, far[i].copy()
        else:  # the head says nearer than the box bottom allows: cover both
            new_near, new_far = far[i].copy(), head_near
        if not located[i] or float(np.hypot(*(new_near - c_xy))) < \
                float(np.hypot(*(near[i] - c_xy))):
            near[i] = new_near
        far[i] = new_far
        located[i] = True
        px, front = model.project(np.array([[near[i, 0], near[i, 1], 0.0]]))
        bottom_px[i] = max(bottom_px[i], float(px[0, 1])) if front[0] else float(height)
    return Placement(near, far, located, hidden, u, y_far, bottom_px)


def occluder_outline_px(points_m: np.ndarray, model: geo.CameraModel) -> np.ndarray | None:
    """Image outline (convex hull, raw pixels) of an occluder given by its corner points, or
    None when it is behind the camera or the camera cannot project heights."""
    if not model.can_project_3d:
        return None
    px, front = model.project(np.asarray(points_m, float).reshape(-1, 3))
    if not front.all():
        return None
    return cv2.convexHull(px.astype(np.float32)).reshape(-1, 2).astype(float)


def segments_hit_polygons(u: np.ndarray, y0: np.ndarray, y1: np.ndarray,
                          edges: geo._PolygonEdges) -> np.ndarray:
    """(N, Z) bool: the vertical pixel segment x = u, y0 <= y <= y1 touches polygon z."""
    n = len(u)
    out = edges.contains(np.c_[u, y0]) | edges.contains(np.c_[u, y1])
    if edges.count == 0 or n == 0:
        return out
    # an edge that crosses the column x = u between y0 and y1 (non-vertical in x)
    x0 = edges.x0
    y_a = edges.y0
    slope = edges.dx_dy
    # edge end points: recover x1 from the edge's y span and slope (x0 + (y1 - y0) * slope)
    y_b = np.where(np.isclose(edges.ylo, y_a), edges.yhi, edges.ylo)
    x_b = x0 + (y_b - y_a) * slope
    horizontal = edges.ylo == edges.yhi
    lo_x, hi_x = np.minimum(x0, x_b), np.maximum(x0, x_b)
    uu = u[:, None]
    spans = (lo_x <= uu) & (uu <= hi_x)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(slope != 0, 1.0 / np.where(slope != 0, slope, 1.0), np.inf)
        y_cross = np.where(horizontal, y_a, y_a + (uu - x0) * inv)
    # vertical edges (slope 0, not horizontal) lie on one column: touching if in the y range
    vertical = (~horizontal) & (slope == 0)
    touch_v = vertical & np.isclose(x0, uu) & (edges.ylo <= y1[:, None]) \
        & (edges.yhi >= y0[:, None])
    cross = spans & ~vertical & (y_cross >= y0[:, None]) & (y_cross <= y1[:, None])
    hit = cross | touch_v
    starts = edges.starts
    return out | (np.add.reduceat(hit.astype(np.int32), starts, axis=1) > 0)


# --------------------------------------------------------------------------------------------
# Shadows


def shadowed(floor_xy_m: np.ndarray, model: geo.CameraModel, occluders_contain,
             min_height_m: float, samples: int = 48) -> np.ndarray:
    """(N,) bool: floor points in this camera's shadow (see the module docstring).

    ``occluders_contain(points (M, 3)) -> (M,) bool`` says which cell points lie inside any
    occluder. The sight line from the camera to each head top is sampled ``samples`` times
    (and its ends excluded); a camera without a pinhole calibration sees no heights, so every
    point counts as shadowed only when its head top is outside the image.
    """
    pts = np.asarray(floor_xy_m, float).reshape(-1, 2)
    n = len(pts)
    heads = np.c_[pts, np.full(n, min_height_m)]
    px, front = model.project(heads)
    inside = front & (px[:, 0] >= 0) & (px[:, 0] < model.width) & (px[:, 1] >= 0) \
        & (px[:, 1] < model.height)
    out = ~inside
    centre = camera_centre_m(model)
    if centre is None or occluders_contain is None or not n:
        return out
    t = (np.arange(1, samples + 1) / (samples + 1))[None, :, None]
    line = centre[None, None, :] + t * (heads[:, None, :] - centre[None, None, :])
    blocked = occluders_contain(line.reshape(-1, 3)).reshape(n, samples).any(axis=1)
    return out | blocked
