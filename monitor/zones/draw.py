"""Zone outlines in an image: watch regions and drawing."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from monitor import geometry as geo
from monitor.errors import ConfigError
from monitor.geometry.occlusion import standable
from monitor.zones.coverage import figure_visible, occluders_contain
from monitor.zones.files import Cell
from monitor.zones.labels import Rect, place_labels
from monitor.zones.moving import cell_from_zone, follows_tool, max_zone, transform_points
from monitor.zones.schema import (
    BoxZone,
    CameraSpec,
    CylinderZone,
    ExtrudeZone,
    MeshZone,
    PolygonZone,
)
from monitor.zones.volumes import box_corners

# --------------------------------------------------------------------------------------------
# Outlines in an image: watch regions and drawing


def volume_outline_m(z: Any, cell: Cell, segments: int = 32) -> list[np.ndarray]:
    """Polylines (each (M, 3), metres) that draw a volume zone as a wireframe."""
    if isinstance(z, ExtrudeZone | CylinderZone):
        if isinstance(z, ExtrudeZone):
            base = np.array(z.points_m, dtype=float)
        else:
            a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
            base = np.c_[z.center_m[0] + z.radius_m * np.cos(a),
                         z.center_m[1] + z.radius_m * np.sin(a)]
        return _prism_lines(base, z.z_min_m, z.z_max_m, vertical=isinstance(z, ExtrudeZone))
    if isinstance(z, BoxZone):
        c = box_corners(z)
        return _prism_lines(c[:4, :2], z.min_m[2], z.max_m[2])
    verts, faces = cell.meshes[z.id]
    edges = np.unique(np.sort(np.r_[faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]],
                              axis=1), axis=0)
    if len(edges) > 3000:  # a dense mesh: draw its bounding box instead
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        base = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        return _prism_lines(base, lo[2], hi[2])
    return [verts[e] for e in edges]


def _prism_lines(base: np.ndarray, z0: float, z1: float, vertical: bool = True
                 ) -> list[np.ndarray]:
    ring = np.r_[base, base[:1]]
    lines = [np.c_[ring, np.full(len(ring), z0)], np.c_[ring, np.full(len(ring), z1)]]
    step = 1 if vertical else max(1, len(base) // 4)
    lines += [np.array([[x, y, z0], [x, y, z1]]) for x, y in base[::step]]
    return lines


def _project_lines(model: geo.CameraModel, lines: list[np.ndarray], samples: int = 24
                   ) -> list[np.ndarray]:
    """Project 3-D polylines; each segment is sampled so that lens distortion bends it, and
    the parts behind the camera are dropped. Returns 2-D polylines in raw pixels."""
    out = []
    for line in lines:
        t = np.linspace(0, 1, samples)[:, None]
        pts = np.concatenate([a + t * (b - a) for a, b in itertools.pairwise(line)])
        px, front = model.project(pts)
        px = np.asarray(px, dtype=float).reshape(-1, 2)
        with np.errstate(invalid="ignore"):
            ok = np.asarray(front, dtype=bool) & (np.abs(px) < 1e6).all(axis=1)
        # runs of consecutive drawable points (a NaN fails the bound too); one point is no line
        edges = np.flatnonzero(np.diff(np.r_[0, ok.astype(np.int8), 0]))
        out += [px[a:b] for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a > 1]
    return out


def volume_region_px(z: Any, cell: Cell, model: geo.CameraModel, cam: CameraSpec
                      ) -> np.ndarray | None:
    """Image outline (convex hull) of a volume zone, clipped to the image; None if unseen."""
    lines = _project_lines(model, volume_outline_m(z, cell), samples=8)
    if not lines:
        return None
    pts = np.concatenate(lines).astype(np.float32)
    hull = cv2.convexHull(pts).reshape(-1, 2)
    clipped = geo.clip_polygon_to_rect(hull, cam.width, cam.height)
    if len(clipped) < 3 or abs(geo.polygon_signed_area(clipped)) < 1.0:
        return None
    return clipped


def watch_regions(cell: Cell, camera_id: str) -> list[tuple[str, np.ndarray]]:
    """Enabled ``watch`` zones seen by one camera: (zone id, polygon (K, 2) float32 pixels).

    Image zones are returned as drawn; volume zones as the convex hull of their projection
    through the camera's calibration, clipped to the image (homography-only cameras see the
    floor footprint only). Volume zones out of view, or cameras without calibration, give none.
    """
    cam = cell.cameras.get(camera_id)
    if cam is None:
        raise ConfigError(f"{cell.label}: unknown camera '{camera_id}'")
    model = cell.camera_models.get(camera_id)
    out = []
    for z in cell.zones:
        if z.kind != "watch" or not z.enabled:
            continue
        if isinstance(z, PolygonZone):
            if z.camera == camera_id:
                out.append((z.id, np.array(z.points_px, dtype=np.float32)))
        elif model is not None:
            region = volume_region_px(z, cell, model, cam)
            if region is not None:
                out.append((z.id, region.astype(np.float32)))
    return out


COLOURS_BGR = {
    "protective": (40, 40, 230),
    "warning": (0, 170, 255),
    "mask": (170, 170, 170),
    "watch": (230, 160, 30),
    "occluder": (120, 90, 60),
}
SHADOW_BGR = (60, 20, 60)
FLOOR_BGR = (80, 160, 60)  # raised or sunken floor regions (zone file floors:)


def draw_zones(frame_bgr: np.ndarray, cell: Cell, camera_id: str,
               hit_zone_ids: Iterable[str] = (), legend: bool = False,
               tool_pose: geo.ToolPose | None = None,
               cache: ZoneDrawCache | None = None) -> np.ndarray:
    """A copy of the frame with the camera's zones drawn and labelled (see
    ``draw_zones_labelled``); ``legend``: with the colour legend in the top-right corner.
    ``cache``: what a caller drawing the camera again and again keeps (the shadow behind the
    occluders took 0.4 s a frame to compute on the demo cell)."""
    reserved: list[Rect] = []
    if legend:
        reserved.append(legend_rect(frame_bgr.shape[1], LEGEND_TOP_PX))
    img, _ = draw_zones_labelled(frame_bgr, cell, camera_id, hit_zone_ids, reserved,
                                 tool_pose, cache=cache)
    if legend:
        draw_legend(img, LEGEND_TOP_PX)
    return img


@dataclass(frozen=True)
class ZoneLabel:
    """A label as drawn: its text, where (x1, y1, x2, y2 pixels) and in which colour."""

    text: str
    rect: Rect
    colour: tuple[int, int, int]


def draw_zones_labelled(frame_bgr: np.ndarray, cell: Cell, camera_id: str,
                        hit_zone_ids: Iterable[str] = (), reserved: Sequence[Rect] = (),
                        tool_pose: geo.ToolPose | None = None,
                        cache: ZoneDrawCache | None = None
                        ) -> tuple[np.ndarray, list[ZoneLabel]]:
    """A copy of the frame with the camera's zones drawn and labelled, and the labels drawn.

    Image zones are filled (translucent) and outlined; volume zones are projected through the
    calibration as wireframes with a filled floor footprint; floor regions (platforms, pits)
    as their standing surface, labelled with its height. Zones in ``hit_zone_ids`` are drawn
    thicker and labelled HIT. Labels never overlap each other nor ``reserved`` rectangles
    (``monitor.zones.labels``): the most important zones' labels are placed first. A frame of
    another size than the camera is drawn scaled. Zones that follow the tool are drawn at
    ``tool_pose`` (a tracker pose, not grown), or at their maximum volume without one.
    ``cache`` keeps what does not change from frame to frame (the projected shapes, the
    shadow, the label places): a video's frames are drawn the same, only faster.
    """
    cam = cell.cameras.get(camera_id)
    if cam is None:
        raise ConfigError(f"{cell.label}: unknown camera '{camera_id}'")
    img = np.ascontiguousarray(frame_bgr).copy()
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    cache = cache if cache is not None else ZoneDrawCache()
    cache.use(cell, camera_id, img.shape[1], img.shape[0])
    scale = np.array([img.shape[1] / cam.width, img.shape[0] / cam.height])
    hit = set(hit_zone_ids)
    model = cell.camera_models.get(camera_id)
    shapes: list[ZoneShape] = []
    # most important last, so that protective zones stay visible on top of warning areas
    order = {"watch": 0, "mask": 1, "occluder": 2, "warning": 3, "protective": 4}
    for z in sorted(cell.zones, key=lambda z: order[z.kind]):
        if not z.enabled or (isinstance(z, PolygonZone) and z.camera != camera_id) \
                or (not isinstance(z, PolygonZone) and model is None):
            continue
        if follows_tool(z) and tool_pose is not None:  # moves with the tool: every frame
            shape = _zone_shape(z, cell, model, scale, tool_pose)
        else:
            shape = cache.shape(z.id, lambda z=z: _zone_shape(z, cell, model, scale, None))
        if shape is not None:
            shapes.append(shape)
    if model is not None:
        shapes += cache.shape(_FLOORS, lambda: _floor_shapes(cell, model, scale))
    fills = img.copy()
    for shape in shapes:
        if shape.fill is not None:
            cv2.fillPoly(fills, [shape.fill], shape.colour, lineType=cv2.LINE_AA, shift=4)
    if model is not None:
        cache.paint_shadow(fills)
    cv2.addWeighted(fills, 0.35, img, 0.65, 0, dst=img)
    outlined = [s for s in shapes if s.lines]
    for shape in outlined:
        thick = 4 if shape.label in hit else 2
        cv2.polylines(img, shape.lines_i32, len(shape.lines) == 1, shape.colour, thick,
                      cv2.LINE_AA, 4)
    # labels last, over every outline; placed from the most important (drawn last) down
    texts = [(f"{s.label}{' HIT' if s.label in hit else ''}", s) for s in reversed(outlined)]
    sizes = [_label_size(t) for t, _ in texts]
    anchors = [_label_anchor(s.lines, size) for (_, s), size in zip(texts, sizes, strict=True)]
    key = (tuple(t for t, _ in texts), tuple(anchors), tuple(map(tuple, reserved)))
    rects = cache.label_places(key, lambda: place_labels(anchors, sizes, img.shape[1],
                                                         img.shape[0], reserved))
    labels = []
    for (text, shape), rect in zip(texts, rects, strict=True):
        if rect is not None:
            _draw_label(img, text, rect, shape.colour)
            labels.append(ZoneLabel(text, rect, shape.colour))
    return img, labels


@dataclass(frozen=True)
class ZoneShape:
    """A zone (or floor region) as drawn in one image: its translucent fill (fixed-point
    pixels, or None), its outline polylines (pixels and fixed-point), colour and label."""

    label: str
    colour: tuple[int, int, int]
    fill: np.ndarray | None
    lines: list[np.ndarray]
    lines_i32: list[np.ndarray]


def _shape(label: str, colour: tuple[int, int, int], fill: np.ndarray | None,
           lines: list[np.ndarray]) -> ZoneShape:
    return ZoneShape(label, colour, None if fill is None else _i32(fill), lines,
                     [_i32(p) for p in lines])


def _zone_shape(z: Any, cell: Cell, model: geo.CameraModel | None, scale: np.ndarray,
                tool_pose: geo.ToolPose | None) -> ZoneShape | None:
    """An enabled zone the camera sees, in the image's pixels; None when out of view."""
    colour = COLOURS_BGR[z.kind]
    if isinstance(z, PolygonZone):
        poly = np.array(z.points_px) * scale
        return _shape(z.id, colour, poly, [poly])
    if model is None:
        return None
    shape, at = z, None
    if follows_tool(z):  # at the pose; without one (stale) at its maximum size
        at = cell_from_zone(cell.spec, tool_pose) if tool_pose is not None else None
        shape = z if at is not None else max_zone(z)
    outline = volume_outline_m(shape, cell)
    if at is not None:
        outline = [transform_points(at, ln) for ln in outline]
    projected = _project_lines(model, outline)
    if not projected:
        return None
    region = _volume_floor_px(shape, cell, model) if at is None else \
        cv2.convexHull(np.concatenate(projected).astype(np.float32)).reshape(-1, 2)
    return _shape(z.id, colour, None if region is None else region * scale,
                  [ln * scale for ln in projected])


def _floor_shapes(cell: Cell, model: geo.CameraModel, scale: np.ndarray) -> list[ZoneShape]:
    """Each floor region's standing surface (at its height; a homography sees only the
    cell floor, so there the footprint) and its wireframe from the cell floor up or down to
    it, labelled with the height (a surface without a drawable wireframe: filled only)."""
    out = []
    for f in cell.spec.floors:
        base = np.asarray(f.points_m, float)
        h = f.height_m if model.can_project_3d else 0.0
        lines = [ln * scale for ln in _project_lines(model, _prism_lines(base, 0.0, h))]
        top = _project_lines(model, _prism_lines(base, h, h)[:1], samples=8)
        fill = top[0] * scale if len(top) == 1 else None
        if lines or fill is not None:
            out.append(_shape(f"{f.id} {f.height_m:+g} m", FLOOR_BGR, fill, lines))
    return out


_FLOORS = object()  # the cache's key for the floor regions' shapes
_MAX_LABEL_LAYOUTS = 64  # label layouts kept (hits and header rows vary between frames)


class ZoneDrawCache:
    """What drawing one camera's zones keeps from frame to frame: the projected shapes of the
    zones that do not move, the shadow behind the occluders and the label places last
    computed. They depend only on the cell (its zones, occluders and calibration), the camera
    and the image size; a zone swap brings a new Cell, and the cell is kept, so a new one is
    never taken for it. Projecting the shapes and placing the labels was most of the drawing;
    the shadow is painted with one masked copy (a boolean index of a 1280x720 image took
    tens of milliseconds)."""

    def __init__(self) -> None:
        self._key: tuple[Cell, str, int, int] | None = None
        self._shapes: dict[object, Any] = {}
        self._labels: dict[tuple, list] = {}
        self._shadow: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._shadow_done = False

    def use(self, cell: Cell, camera_id: str, width: int, height: int) -> None:
        """Draw for this cell, camera and image size from now on (forgets any other's)."""
        key = (cell, camera_id, width, height)
        if self._key is None or self._key[0] is not cell or self._key[1:] != key[1:]:
            self._key = key
            self._shapes, self._labels = {}, {}
            self._shadow, self._shadow_done = None, False

    def shape(self, key: object, make: Callable[[], Any]) -> Any:
        if key not in self._shapes:
            self._shapes[key] = make()
        return self._shapes[key]

    def label_places(self, key: tuple, make: Callable[[], list]) -> list:
        if key not in self._labels:
            if len(self._labels) >= _MAX_LABEL_LAYOUTS:
                self._labels.clear()
            self._labels[key] = make()
        return self._labels[key]

    def shadow(self, cell: Cell, camera_id: str, width: int, height: int
               ) -> np.ndarray | None:
        """(height, width) bool: the camera's shadow image (``shadow_image``), kept."""
        self.use(cell, camera_id, width, height)
        if not self._shadow_done:
            mask = shadow_image(cell, camera_id, width, height)
            if mask is not None:
                colour = np.empty((height, width, 3), np.uint8)
                colour[:] = SHADOW_BGR
                self._shadow = (mask, mask.astype(np.uint8), colour)
            self._shadow_done = True
        return None if self._shadow is None else self._shadow[0]

    def paint_shadow(self, fills: np.ndarray) -> None:
        """Paint the shadow of the cell, camera and size last used onto ``fills``."""
        if self._key is not None and self.shadow(*self._key) is not None:
            assert self._shadow is not None
            cv2.copyTo(self._shadow[2], self._shadow[1], fills)


def shadow_image(cell: Cell, camera_id: str, width: int, height: int, step_px: int = 8
                 ) -> np.ndarray | None:
    """(height, width) bool: image pixels whose floor point lies in the camera's shadow behind
    the cell's occluders: less of the smallest posture than the detector needs is in view
    there (``coverage.figure_visible``, the visibility the lost persons' areas use), or None
    without occluders or calibration. Evaluated every ``step_px`` pixels of the camera and
    scaled to ``width`` x ``height``."""
    occluders = cell.spec.occluder_zones()  # the robot base included
    model = cell.camera_models.get(camera_id)
    cam = cell.cameras[camera_id]
    if not occluders or model is None:
        return None
    us = np.arange(step_px / 2, cam.width, step_px)
    vs = np.arange(step_px / 2, cam.height, step_px)
    gu, gv = np.meshgrid(us, vs)
    floor, ok = model.pixel_to_floor(np.c_[gu.ravel(), gv.ravel()])
    mask = np.zeros(len(floor), dtype=bool)
    idx = np.flatnonzero(ok)
    if len(idx):
        pts = floor[idx]
        p = cell.spec.person
        seen = figure_visible(model, pts, p.smallest_height_m, p.needed_fraction, p.radius_m,
                              occluders_contain(occluders, cell.meshes))
        mask[idx] = ~seen & standable(occluders, cell.meshes, pts)
    small = mask.reshape(len(vs), len(us)).astype(np.uint8)
    return cv2.resize(small, (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)


def _volume_floor_px(z: Any, cell: Cell, model: geo.CameraModel) -> np.ndarray | None:
    """Projected footprint of a volume at its lowest z (for the translucent fill)."""
    lines = volume_outline_m(z, cell)
    if isinstance(z, MeshZone):
        return None
    bottom = _project_lines(model, lines[:1], samples=8)
    if len(bottom) != 1:
        return None
    return bottom[0]


def _i32(p: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(p) * 16).astype(np.int32)


LABEL_FONT = cv2.FONT_HERSHEY_SIMPLEX
LABEL_SCALE = 0.5


def _label_size(text: str) -> tuple[int, int]:
    """(w, h) of a label's rectangle: the text and a 2 px margin around it."""
    (w, th), base = cv2.getTextSize(text, LABEL_FONT, LABEL_SCALE, 1)
    return w + 4, th + base + 4


def _label_anchor(polys: list[np.ndarray], size: tuple[int, int]) -> tuple[float, float]:
    """Where a zone's label wants its top-left corner: just above the top-left-most point of
    the zone's outline."""
    pts = np.concatenate(polys)
    near_top = pts[pts[:, 1] <= pts[:, 1].min() + 1.0]
    top = near_top[int(np.argmin(near_top[:, 0]))]
    return float(top[0]), float(top[1]) - size[1] - 2


def _draw_label(img: np.ndarray, text: str, rect: Rect, colour: tuple[int, int, int]) -> None:
    x1, y1, x2, y2 = rect
    cv2.rectangle(img, (x1, y1), (x2 - 1, y2 - 1), (0, 0, 0), -1)
    (_, th), _ = cv2.getTextSize(text, LABEL_FONT, LABEL_SCALE, 1)
    cv2.putText(img, text, (x1 + 2, y1 + 2 + th), LABEL_FONT, LABEL_SCALE, colour, 1, cv2.LINE_AA)


# --------------------------------------------------------------------------------------------
# The legend: one colour per zone kind, the same in `zones preview` and the replay video

LEGEND_KINDS = ("protective", "warning", "mask", "watch")
LEGEND_TOP_PX = 4  # the legend's top edge (replay moves it below its header band)
_LEGEND_ROW_PX = 18
_LEGEND_WIDTH_PX = 132


def legend_rect(width: int, top: int, kinds: Sequence[str] = LEGEND_KINDS) -> Rect:
    """Where the legend goes: the top-right corner, ``top`` pixels down."""
    return (width - _LEGEND_WIDTH_PX - 4, top, width - 4, top + 8 + _LEGEND_ROW_PX * len(kinds))


def draw_legend(img: np.ndarray, top: int, kinds: Sequence[str] = LEGEND_KINDS
                ) -> list[tuple[str, tuple[int, int, int]]]:
    """Draw the legend in place (a swatch and the kind's name per row, in the colours of
    ``COLOURS_BGR``); returns the (kind, colour) rows drawn."""
    x1, y1, x2, y2 = legend_rect(img.shape[1], top, kinds)
    cv2.rectangle(img, (x1, y1), (x2 - 1, y2 - 1), (0, 0, 0), -1)
    cv2.rectangle(img, (x1, y1), (x2 - 1, y2 - 1), (200, 200, 200), 1)
    rows = []
    for k, kind in enumerate(kinds):
        colour = COLOURS_BGR[kind]
        y = y1 + 4 + k * _LEGEND_ROW_PX
        cv2.rectangle(img, (x1 + 6, y + 3), (x1 + 26, y + _LEGEND_ROW_PX - 3), colour, -1)
        cv2.putText(img, f"{kind} zone", (x1 + 32, y + _LEGEND_ROW_PX - 5), LABEL_FONT, 0.45,
                    colour, 1, cv2.LINE_AA)
        rows.append((kind, colour))
    return rows
