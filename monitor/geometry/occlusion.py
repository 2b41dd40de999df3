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
  visible bottom allows. The visible bottom itself stays in the range (the union of both,
  merged into one range towards danger): a short box is also a crouching, kneeling or lying
  person whose feet are in view, and their head is below ``height_range_m[0]``.

The zone check then tests the person cylinder swept along that segment (a stadium on the floor,
extruded to the person height), so every position the evidence allows is tested: a person behind
a bench is found in the protective zone even though the box bottom lies on the bench top.

**Shadows.** A floor point is in a camera's *shadow* when a person of the minimum height
(``height_range_m[0]``) standing there would be wholly hidden from that camera: the sight line
from the camera to the top of their head passes through an occluder, or that head is outside the
image or behind the camera. Persons whose head shows are placed from the head (above); persons in
a shadow of every camera cannot be seen at all: ``zones validate`` refuses protective zone floor
there, or flags it (monitor/zones/coverage.py).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from monitor import geometry as geo
from monitor.geometry.floors import FloorRegion, plane_hits
from monitor.geometry.sight import sight_blocked

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
    bottom-centre anchor); ``feet_u_px`` (N,) the column. ``stand_lo_m``/``stand_hi_m`` (N,):
    the lowest and highest surface the person may stand on along the range (0 = the cell floor;
    a declared floor region's height where the range reaches onto it).
    """

    near_m: np.ndarray
    far_m: np.ndarray
    located: np.ndarray
    hidden: np.ndarray
    feet_u_px: np.ndarray
    feet_top_px: np.ndarray
    feet_bottom_px: np.ndarray
    stand_lo_m: np.ndarray | None = None
    stand_hi_m: np.ndarray | None = None

    @property
    def length_m(self) -> np.ndarray:
        return np.hypot(*(self.far_m - self.near_m).T)


def camera_centre_m(model: geo.CameraModel) -> np.ndarray | None:
    """Camera centre in the cell frame, or None for a homography-only calibration."""
    if model.rotation is None or model.translation_m is None:
        return None
    return -model.rotation.T @ model.translation_m


def project_px(model: geo.CameraModel, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``model.project`` without OpenCV's per-call set-up when the lens has no distortion
    (the per-frame path projects a handful of points)."""
    if model.rotation is None or (model.distortion is not None and np.any(model.distortion)):
        return model.project(points_m)
    cam = points_m @ model.rotation.T + model.translation_m
    front = cam[:, 2] > 1e-6
    z = np.where(front, cam[:, 2], 1.0)
    k = model.camera_matrix
    px = np.empty((len(cam), 2))
    px[:, 0] = k[0, 0] * cam[:, 0] / z + k[0, 1] * cam[:, 1] / z + k[0, 2]
    px[:, 1] = k[1, 1] * cam[:, 1] / z + k[1, 2]
    return px, front


def pixel_rays(model: geo.CameraModel, px: np.ndarray) -> np.ndarray:
    """Unit viewing directions (N, 3) in the cell frame of raw pixels (pinhole cameras only)."""
    und = model.undistort_px(px)
    k = model.camera_matrix
    d_cam = np.c_[(und[:, 0] - k[0, 2]) / k[0, 0], (und[:, 1] - k[1, 2]) / k[1, 1],
                  np.ones(len(und))]
    d = d_cam @ model.rotation  # R^T d_cam, row-wise
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass(frozen=True, eq=False)
class OccluderColumns:
    """Where a camera's occluder outlines are, as per-column running counts of outline pixels
    (dilated by ``EDGE_TOLERANCE_PX``): "does column u meet an outline between rows a and b"
    is two look-ups. Built once per camera."""

    counts: np.ndarray  # (height + 1, width) int32: outline pixels above each row, per column

    @classmethod
    def build(cls, outlines_px: Sequence[np.ndarray], width: int, height: int
              ) -> OccluderColumns | None:
        if not outlines_px:
            return None
        mask = np.zeros((height, width), np.uint8)
        for outline in outlines_px:
            pts = np.round(np.asarray(outline, float) * 16).astype(np.int32)
            cv2.fillPoly(mask, [pts], 1, cv2.LINE_8, shift=4)
        return cls.of_mask(mask)

    @classmethod
    def of_mask(cls, mask: np.ndarray) -> OccluderColumns:
        """The columns of any (H, W) mask of edge pixels (e.g. the reference image's
        horizontal edges, ``monitor.geometry.edges``), dilated by ``EDGE_TOLERANCE_PX``."""
        mask = np.asarray(mask).astype(np.uint8)
        height, width = mask.shape
        r = math.ceil(EDGE_TOLERANCE_PX)
        mask = cv2.dilate(mask, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
        counts = np.zeros((height + 1, width), np.int32)
        np.cumsum(mask, axis=0, out=counts[1:])
        return cls(counts)

    def meets(self, u: np.ndarray, y0: np.ndarray, y1: np.ndarray) -> np.ndarray:
        """(N,) bool: column ``u`` holds outline pixels between rows ``y0`` and ``y1``."""
        h, w = self.counts.shape[0] - 1, self.counts.shape[1]
        col = np.clip(np.floor(u), 0, w - 1).astype(np.intp)
        a = np.clip(np.floor(y0), 0, h).astype(np.intp)
        b = np.clip(np.floor(y1) + 1, 0, h).astype(np.intp)
        return self.counts[b, col] > self.counts[a, col]


def feet_may_be_hidden(boxes_px: np.ndarray, model: geo.CameraModel | None, width: int,
                       height: int, occluder_outlines_px: Sequence[np.ndarray] = (),
                       min_height_m: float = 1.0, band_hi_px: float = 0.0,
                       occluder_columns: OccluderColumns | None = None,
                       bottom_floor: tuple[np.ndarray, np.ndarray] | None = None,
                       edge_columns: OccluderColumns | None = None
                       ) -> np.ndarray:
    """(N,) bool: the feet of each box may be hidden, by the image's bottom edge, an occluder
    (the box bottom, or up to ``band_hi_px`` below it, on an occluder's image outline), a
    horizontal edge of the commissioning reference (``edge_columns``: a fixture's top edge,
    declared or not, between ``band_hi_px`` above the box bottom and just below it, in the
    middle half of the box), or because the box is shorter than a person of ``min_height_m``
    at the floor point its bottom implies (a pinhole calibration is needed for the outlines and
    the height). ``occluder_columns`` is the prepared form of ``occluder_outlines_px``
    (faster); give one or the other. ``bottom_floor``: ``model.pixel_to_floor`` of the boxes'
    bottom-centres, when known."""
    boxes = np.asarray(boxes_px, float).reshape(-1, 4)
    n = len(boxes)
    hidden = boxes[:, 3] >= height - EDGE_TOLERANCE_PX
    if not n:
        return hidden
    u = (boxes[:, 0] + boxes[:, 2]) * 0.5
    reach = max(EDGE_TOLERANCE_PX, band_hi_px)
    if occluder_columns is None and len(occluder_outlines_px):
        occluder_columns = OccluderColumns.build(occluder_outlines_px, width, height)
    if occluder_columns is not None:
        hidden |= occluder_columns.meets(u, boxes[:, 3], boxes[:, 3] + reach)
    if edge_columns is not None:
        hidden |= on_reference_edge(boxes, edge_columns, band_hi_px)
    if model is not None and model.can_project_3d:
        if bottom_floor is None:
            bottom_floor = model.pixel_to_floor(np.column_stack((u, boxes[:, 3])))
        floor, ok = bottom_floor
        pts = np.zeros((2 * n, 3))
        pts[:n, :2] = floor
        pts[n:, :2] = floor
        pts[n:, 2] = min_height_m
        px, front = project_px(model, pts)
        expected = px[:n, 1] - px[n:, 1]
        hidden |= ok & front[:n] & front[n:] & (boxes[:, 3] - boxes[:, 1] < expected)
    return hidden


def on_reference_edge(boxes_px: np.ndarray, edge_columns: OccluderColumns,
                      band_hi_px: float = 0.0) -> np.ndarray:
    """(N,) bool: the lower edge of each box lies on a horizontal edge of the reference
    (``edge_columns``, ``OccluderColumns.of_mask`` of ``geometry.edges.horizontal_edges``):
    in one of three columns across the middle half of the box, between ``band_hi_px`` above
    its bottom (where the visible feet may end: the detector's box error) and
    ``EDGE_TOLERANCE_PX`` below it."""
    boxes = np.asarray(boxes_px, float).reshape(-1, 4)
    out = np.zeros(len(boxes), dtype=bool)
    y0 = boxes[:, 3] - max(band_hi_px, 0.0) - EDGE_TOLERANCE_PX
    y1 = boxes[:, 3] + EDGE_TOLERANCE_PX
    for share in (0.25, 0.5, 0.75):
        u = boxes[:, 0] + share * (boxes[:, 2] - boxes[:, 0])
        out |= edge_columns.meets(u, y0, y1)
    return out


def place_persons(boxes_px: np.ndarray, model: geo.CameraModel, width: int, height: int, *,
                  band_px: tuple[float, float] = (0.0, 0.0),
                  height_range_m: tuple[float, float] = (1.0, 2.0),
                  occluder_outlines_px: Sequence[np.ndarray] = (),
                  occluder_columns: OccluderColumns | None = None,
                  camera_centre: np.ndarray | None = None,
                  floors: Sequence[FloorRegion] = (),
                  edge_columns: OccluderColumns | None = None) -> Placement:
    """Where each box's person may stand (see the module docstring).

    ``band_px`` = (lo, hi): the feet lie ``lo`` .. ``hi`` pixels above the box's bottom edge.
    ``occluder_columns`` and ``camera_centre`` are prepared forms (built once per camera) of
    ``occluder_outlines_px`` and ``camera_centre_m(model)``. ``floors``: raised or sunken floor
    regions (``monitor.geometry.floors``); a foot or head sight line that meets one adds that
    position, and the range spans every candidate (pinhole cameras only). ``edge_columns``:
    the commissioning reference's horizontal edges (``on_reference_edge``), or None.
    """
    boxes = np.asarray(boxes_px, float).reshape(-1, 4)
    n = len(boxes)
    lo, hi = float(band_px[0]), float(max(band_px))
    u = (boxes[:, 0] + boxes[:, 2]) * 0.5
    y_far = np.maximum(boxes[:, 3] - hi, boxes[:, 1] + 1.0)
    y_near = np.maximum(boxes[:, 3] - lo, y_far)
    both, ok = model.pixel_to_floor(np.column_stack((np.concatenate((u, u)),
                                                     np.concatenate((y_far, y_near)))))
    far, near = both[:n].copy(), both[n:].copy()
    located = ok[:n] & ok[n:]
    bottom_px = y_near.copy()
    bottom = (near, ok[n:]) if lo == 0.0 else None
    hidden = feet_may_be_hidden(boxes, model, width, height, occluder_outlines_px,
                                height_range_m[0], hi, occluder_columns, bottom,
                                edge_columns)
    centre = camera_centre if camera_centre is not None else camera_centre_m(model)
    stand_lo, stand_hi = np.zeros(n), np.zeros(n)
    floors = tuple(floors) if centre is not None and model.can_project_3d else ()
    if centre is not None and model.can_project_3d:
        _widen_tall_boxes(boxes, model, u, near, far, located, y_far, centre,
                          height_range_m, hi)
        if floors and n:
            _feet_on_floors(model, centre, floors, u, y_far, y_near, near, far, located,
                            stand_lo, stand_hi)
    todo = np.flatnonzero(hidden)
    if centre is None or not len(todo):
        return Placement(near, far, located, hidden, u, y_far, bottom_px, stand_lo, stand_hi)
    h_min, h_max = height_range_m
    c_xy = centre[:2]
    # the head is at the box top, or up to the band lower (a box may reach above the head too)
    heads = np.r_[np.c_[u[todo], boxes[todo, 1]], np.c_[u[todo], boxes[todo, 1] + hi]]
    rays = pixel_rays(model, heads)
    m = len(todo)
    # heads over a floor region: the floor points under them, where they lie on the region
    raised = [plane_hits(centre, rays, floors, above) for above in (h_min, h_max)] \
        if floors else []
    region_h = np.array([f.height_m for f in floors])
    moved: list[int] = []
    for j, i in enumerate(todo.tolist()):
        cands = []  # floor points under the head at each end of the height range
        for xy, ok in raised:
            for row in (j, m + j):
                on = np.flatnonzero(ok[row])
                cands.extend(xy[row, on])
                if len(on):
                    stand_lo[i] = min(stand_lo[i], float(region_h[on].min()))
                    stand_hi[i] = max(stand_hi[i], float(region_h[on].max()))
        # a level or rising sight line: the head may be arbitrarily far
        # a head cut by the image's top edge may be anywhere above it: from right under the
        # camera out to as far as the feet allow
        top_cut = bool(boxes[i, 1] <= EDGE_TOLERANCE_PX)
        unbounded = top_cut
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
        head_near = cands[int(np.argmin(dist))] if cands and not top_cut else c_xy.copy()
        d_near = min(dist) if cands and not top_cut else 0.0
        d_vis = float(np.hypot(*(far[i] - c_xy))) if located[i] else np.inf
        # the feet are hidden below the visible bottom (never farther than it allows), or they
        # are at it: a crouching, kneeling or lying person is short with the feet in view.
        # Keep both, the head's range and the feet's, as one range (merged towards danger).
        if d_near <= d_vis:
            new_near, new_far = head_near, far[i].copy()
        else:  # the head says farther than the box bottom allows: cover both
            new_near, new_far = far[i].copy(), head_near
        if not located[i] or float(np.hypot(*(new_near - c_xy))) < \
                float(np.hypot(*(near[i] - c_xy))):
            near[i] = new_near
        far[i] = new_far
        located[i] = True
        moved.append(i)
    if moved:  # the feet's lowest image row: where the nearest floor position projects
        idx = np.array(moved, dtype=np.intp)
        pts = np.zeros((len(idx), 3))
        pts[:, :2] = near[idx]
        px, front = project_px(model, pts)
        bottom_px[idx] = np.where(front, np.maximum(bottom_px[idx], px[:, 1]), float(height))
    return Placement(near, far, located, hidden, u, y_far, bottom_px, stand_lo, stand_hi)


def _feet_on_floors(model: geo.CameraModel, centre: np.ndarray, floors: Sequence[FloorRegion],
                    u: np.ndarray, y_far: np.ndarray, y_near: np.ndarray, near: np.ndarray,
                    far: np.ndarray, located: np.ndarray, stand_lo: np.ndarray,
                    stand_hi: np.ndarray) -> None:
    """Widen each feet range (in place) over the floor regions its foot rows' sight lines
    meet: a foot pixel is a point on the cell floor *and* on every region its ray meets there,
    and the evidence cannot tell which, so the range runs from the nearest of them to the
    farthest (merged towards danger). A person on a 1 m platform is otherwise placed metres
    beyond it, where the same pixel meets the floor."""
    n = len(u)
    rays = pixel_rays(model, np.c_[np.r_[u, u], np.r_[y_far, y_near]])
    xy, ok = plane_hits(centre, rays, floors)
    heights = np.array([f.height_m for f in floors])
    c = centre[:2]
    for i in np.flatnonzero(located & (ok[:n].any(axis=1) | ok[n:].any(axis=1))).tolist():
        on_far, on_near = np.flatnonzero(ok[i]), np.flatnonzero(ok[n + i])
        pts = np.r_[near[i][None], far[i][None], xy[i, on_far], xy[n + i, on_near]]
        dist = np.hypot(*(pts - c).T)
        near[i], far[i] = pts[int(np.argmin(dist))], pts[int(np.argmax(dist))]
        h = heights[np.r_[on_far, on_near]]
        stand_lo[i] = min(stand_lo[i], float(h.min()))
        stand_hi[i] = max(stand_hi[i], float(h.max()))


# how far along a level or rising sight line a person's head may be (metres): beyond any cell
FAR_M = 50.0


def _widen_tall_boxes(boxes: np.ndarray, model: geo.CameraModel, u: np.ndarray,
                      near: np.ndarray, far: np.ndarray, located: np.ndarray,
                      y_far: np.ndarray, centre: np.ndarray,
                      height_range_m: tuple[float, float], band_px: float) -> None:
    """A box taller than the tallest person (``height_range_m[1]``) standing at its bottom
    holds more than one person: boxes merged, or a person standing behind another whose legs
    the nearer one hides. Its top is then someone's head *farther* away than the bottom says,
    so the floor range is widened (in place) out to where that head puts the feet, over the
    whole height range. Without it the person behind disappears into the nearer one's box."""
    idx = np.flatnonzero(located)
    if not len(idx):
        return
    h_max = height_range_m[1]
    heads = np.c_[near[idx], np.full(len(idx), h_max)]
    px, front = project_px(model, heads)
    # a top cut by the image edge is no head (the hidden-feet pass places such boxes)
    tall = front & (boxes[idx, 1] < px[:, 1] - band_px) & (boxes[idx, 1] > EDGE_TOLERANCE_PX)
    rows = idx[tall]
    if not len(rows):
        return
    c = centre[:2]
    rays = pixel_rays(model, np.c_[u[rows], boxes[rows, 1]])  # one call for every tall box
    down = rays[:, 2] < -1e-9
    s_far = np.where(down, (height_range_m[0] - centre[2]) / np.where(down, rays[:, 2], -1.0),
                     -1.0)
    flat = np.hypot(rays[:, 0], rays[:, 1])
    # a level or rising sight line: the head may be anywhere along it, beyond
    along = np.where(flat[:, None] > 1e-9, rays[:, :2] / np.maximum(flat, 1e-12)[:, None], 0.0)
    far_xy = np.where((s_far > 0)[:, None], c + s_far[:, None] * rays[:, :2], c + FAR_M * along)
    placeable = (s_far > 0) | (flat > 1e-9)
    located[rows[~placeable]] = False  # straight up: cannot be placed (inside every volume)
    wider = placeable & (np.hypot(*(far_xy - c).T) > np.hypot(*(far[rows] - c).T))
    if not wider.any():
        return
    grow = rows[wider]
    far[grow] = far_xy[wider]
    pts = np.zeros((len(grow), 3))
    pts[:, :2] = far_xy[wider]
    row_px, ok = project_px(model, pts)
    y_far[grow] = np.where(ok, np.minimum(y_far[grow], row_px[:, 1]), y_far[grow])

def occluder_outline_px(points_m: np.ndarray, model: geo.CameraModel) -> np.ndarray | None:
    """Image outline (convex hull, raw pixels) of an occluder given by its corner points, or
    None when it is behind the camera or the camera cannot project heights."""
    if not model.can_project_3d:
        return None
    px, front = model.project(np.asarray(points_m, float).reshape(-1, 3))
    if not front.all():
        return None
    return cv2.convexHull(px.astype(np.float32)).reshape(-1, 2).astype(float)


@dataclass(frozen=True)
class PolygonSegments:
    """Edges of several image polygons, stacked, for vertical-segment tests."""

    inside: geo.PolygonEdges  # the even-odd point test of the same polygons
    ax: np.ndarray
    ay: np.ndarray
    bx: np.ndarray
    by: np.ndarray
    starts: np.ndarray  # index of the first edge of each polygon

    @classmethod
    def build(cls, polygons: Sequence[np.ndarray]) -> PolygonSegments:
        ps = [np.asarray(p, float).reshape(-1, 2) for p in polygons]
        if not ps:
            z = np.zeros(0)
            return cls(geo.PolygonEdges.build([]), z, z, z, z, np.zeros(0, dtype=np.intp))
        a = np.concatenate(ps)
        b = np.concatenate([np.roll(p, -1, axis=0) for p in ps])
        starts = np.cumsum([0] + [len(p) for p in ps[:-1]]).astype(np.intp)
        return cls(geo.PolygonEdges.build(ps), a[:, 0], a[:, 1], b[:, 0], b[:, 1], starts)

    @property
    def count(self) -> int:
        return len(self.starts)


def segments_hit_polygons(u: np.ndarray, y0: np.ndarray, y1: np.ndarray,
                          polys: PolygonSegments) -> np.ndarray:
    """(N, Z) bool: the vertical pixel segment x = u, y0 <= y <= y1 touches polygon z."""
    u, y0, y1 = (np.asarray(v, float).reshape(-1) for v in (u, y0, y1))
    # inside at one end, or crossing an edge (which also covers "inside at the other end")
    out = polys.inside.contains(np.column_stack((u, y0)))
    if polys.count == 0 or len(u) == 0:
        return out
    uu, lo, hi = u[:, None], y0[:, None], y1[:, None]
    ax, ay, bx, by = polys.ax, polys.ay, polys.bx, polys.by
    spans = (np.minimum(ax, bx) <= uu) & (uu <= np.maximum(ax, bx))
    dx = bx - ax
    vertical = dx == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(vertical, 0.0, (uu - ax) / np.where(vertical, 1.0, dx))
    y_cross = ay + t * (by - ay)
    cross = spans & ~vertical & (y_cross >= lo) & (y_cross <= hi)
    # an edge on the column itself: touching when the y ranges overlap
    on = vertical & (ax == uu) & (np.minimum(ay, by) <= hi) & (np.maximum(ay, by) >= lo)
    hit = (cross | on).astype(np.int32)
    return out | (np.add.reduceat(hit, polys.starts, axis=1) > 0)


# --------------------------------------------------------------------------------------------
# Shadows


def shadowed(floor_xy_m: np.ndarray, model: geo.CameraModel, occluders_contain,
             min_height_m: float, samples: int = 48) -> np.ndarray:
    """(N,) bool: floor points in this camera's shadow (see the module docstring).

    ``occluders_contain(points (M, 3)) -> (M,) bool`` says which cell points lie inside any
    occluder. The sight line from the camera to each head top is sampled ``samples`` times
    (and its ends excluded), or, given ``OccluderVolumes``, tested whole over the same span
    (exact sight lines, ``monitor.geometry.sight``); a camera without a
    pinhole calibration sees no heights, so every point counts as shadowed only when its
    head top is outside the image.
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
    if isinstance(occluders_contain, OccluderVolumes):
        return out | occluders_contain.blocks(centre, heads, 1.0 / (samples + 1),
                                              samples / (samples + 1))
    t = (np.arange(1, samples + 1) / (samples + 1))[None, :, None]
    line = centre[None, None, :] + t * (heads[:, None, :] - centre[None, None, :])
    return out | occluders_contain(line.reshape(-1, 3)).reshape(n, samples).any(axis=1)


def points_in_volume(z, points_m: np.ndarray,
                     meshes: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """(M,) bool: cell points inside a volume zone spec (box, extrude, cylinder, mesh)."""
    p = np.asarray(points_m, float).reshape(-1, 3)
    shape = z.shape
    if shape == "box":
        lo, hi = np.array(z.min_m), np.array(z.max_m)
        c = (lo + hi) / 2
        rot = geo.rpy_to_matrix(0, 0, z.yaw_deg)[:2, :2]
        local = (p[:, :2] - c[:2]) @ rot  # rotate back into the box frame
        half = (hi - lo)[:2] / 2
        return np.all(np.abs(local) <= half, axis=1) & (p[:, 2] >= lo[2]) & (p[:, 2] <= hi[2])
    if shape == "extrude":
        inside = geo.points_in_polygon(p[:, :2], np.array(z.points_m, float))
        return inside & (p[:, 2] >= z.z_min_m) & (p[:, 2] <= z.z_max_m)
    if shape == "cylinder":
        c = np.array(z.center_m)
        return (np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]) <= z.radius_m) \
            & (p[:, 2] >= z.z_min_m) & (p[:, 2] <= z.z_max_m)
    verts, faces = meshes[z.id]
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    out = np.all((p >= lo) & (p <= hi), axis=1)
    if out.any():
        out[out] = geo.points_in_mesh(p[out], verts, faces)
    return out


@dataclass(frozen=True)
class OccluderVolumes:
    """A camera's occluders as the sight tests use them: called with points (M, 3), which lie
    inside one; ``blocks`` says which sight lines pass through one, exactly (a sampled line
    missed every occluder thinner than the gap between its samples: a 3 cm screen hid
    nothing, ``monitor.geometry.sight``)."""

    occluders: tuple
    meshes: Mapping[str, tuple[np.ndarray, np.ndarray]]

    def __call__(self, points: np.ndarray) -> np.ndarray:
        out = np.zeros(len(points), dtype=bool)
        for z in self.occluders:
            out |= points_in_volume(z, points, self.meshes)
        return out

    def blocks(self, origin: np.ndarray, ends: np.ndarray, t0: float, t1: float
               ) -> np.ndarray:
        return sight_blocked(self.occluders, self.meshes, origin, ends, t0, t1)


def shadowed_by(occluders: Sequence, meshes: Mapping[str, tuple[np.ndarray, np.ndarray]],
                floor_xy_m: np.ndarray, model: geo.CameraModel, min_height_m: float
                ) -> np.ndarray:
    """``shadowed`` for the occluder zone specs ``occluders`` of a cell."""
    return shadowed(floor_xy_m, model,
                    OccluderVolumes(tuple(occluders), meshes) if occluders else None,
                    min_height_m)


def standable(occluders: Sequence, meshes: Mapping[str, tuple[np.ndarray, np.ndarray]],
              floor_xy_m: np.ndarray) -> np.ndarray:
    """(N,) bool: floor points not inside an occluder's footprint (nobody stands in a bench;
    a conveyor with room beneath is declared from its underside, z_min_m > 0)."""
    pts = np.c_[np.asarray(floor_xy_m, float).reshape(-1, 2), np.full(len(floor_xy_m), 0.01)]
    out = np.ones(len(pts), dtype=bool)
    for z in occluders:
        out &= ~points_in_volume(z, pts, meshes)
    return out


def shadow_mask(cell, camera_id: str, floor_xy_m: np.ndarray) -> np.ndarray:
    """(N,) bool: floor points in the shadow of ``camera_id`` (see the module docstring)."""
    occluders = cell.spec.occluder_zones()  # the robot base included
    model = cell.camera_models[camera_id]
    return shadowed_by(occluders, cell.meshes, floor_xy_m, model,
                       cell.spec.person.height_range_m[0])
