"""The walk test's pictures: a top view of the cell floor (zones, occluders, the cells a person
was seen in, the blind spots) and each camera's image with the same cells drawn in it.

Colours: seen cells green, visible cells the walk never saw a person in grey, blind spots red
(crossed in the camera images), cells where the walker's feet were hidden by an undeclared
fixture crossed in magenta ("feet hidden here: declare an occluder", ``cut_feet``), zone
outlines in the colours of ``monitor zones preview``.
PNG bytes from OpenCV: the same inputs give the same bytes.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from monitor.commission.cut_feet import draw_feet_hidden
from monitor.commission.floor import ZoneFloor
from monitor.commission.walk import WalkResult
from monitor.zones import Cell, draw_zones, volume_outline_m
from monitor.zones.draw import COLOURS_BGR

SEEN_BGR = (60, 170, 60)
UNVISITED_BGR = (170, 170, 170)
BLIND_BGR = (40, 40, 220)
PX_PER_M = 80
MARGIN_M = 0.5


def _floor_lines(cell: Cell, kinds: Sequence[str]) -> list[tuple[str, np.ndarray]]:
    out = []
    for z in cell.zones:
        if z.enabled and z.is_volume and z.kind in kinds:
            out += [(z.kind, line[:, :2]) for line in volume_outline_m(z, cell)]
    occluders = [z for z in cell.spec.occluder_zones() if z not in cell.zones]
    for z in occluders:  # the robot base (always an occluder)
        out += [("occluder", line[:, :2]) for line in volume_outline_m(z, cell)]
    return out


def floor_picture(cell: Cell, floors: Sequence[ZoneFloor], walk: WalkResult | None) -> bytes:
    """PNG: the cell floor from above (x right, y up, metres; the robot base at the origin)."""
    lines = _floor_lines(cell, ("protective", "warning", "occluder"))
    pts = [p for _, line in lines for p in line]
    pts += [c for f in floors for c in f.centres_m]
    if walk is not None:
        pts += list(walk.seen_m)
    pts = np.array(pts, float).reshape(-1, 2) if pts else np.zeros((1, 2))
    lo, hi = pts.min(axis=0) - MARGIN_M, pts.max(axis=0) + MARGIN_M
    size = np.ceil((hi - lo) * PX_PER_M).astype(int)
    img = np.full((int(size[1]) + 30, int(size[0]), 3), 255, np.uint8)

    def px(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        return np.c_[(xy[:, 0] - lo[0]) * PX_PER_M, (hi[1] - xy[:, 1]) * PX_PER_M]

    seen_cells = {}
    if walk is not None:
        for z in walk.zones:
            seen_cells[z.zone_id] = set(z.unvisited)
    for f in sorted(floors, key=lambda f: f.kind != "warning"):  # protective drawn on top
        unvisited = seen_cells.get(f.zone_id)
        half = f.cell_m / 2
        for c, vis in zip(f.centres_m, f.visible, strict=True):
            key = (round(float(c[0]), 3), round(float(c[1]), 3))
            colour = BLIND_BGR if not vis else (
                UNVISITED_BGR if unvisited is None or key in unvisited else SEEN_BGR)
            a, b = px(c - half)[0], px(c + half)[0]
            cv2.rectangle(img, (int(a[0]) + 1, int(b[1]) + 1), (int(b[0]) - 1, int(a[1]) - 1),
                          colour, -1)
    for kind, line in lines:
        cv2.polylines(img, [np.round(px(line)).astype(np.int32)], False,
                      COLOURS_BGR.get(kind, (0, 0, 0)), 2, cv2.LINE_AA)
    if walk is not None and walk.seen_m:
        for p in np.round(px(np.array(walk.seen_m))).astype(int):
            cv2.circle(img, (int(p[0]), int(p[1])), 2, (30, 30, 30), -1)
    if walk is not None:  # where the walker's feet were hidden by an undeclared fixture
        h = half_cell(floors)
        draw_feet_hidden(img, [(px(np.array(c) - h)[0], px(np.array(c) + h)[0])
                               for z in walk.zones for c in z.feet_hidden])
    o = np.round(px(np.zeros(2))[0]).astype(int)
    cv2.drawMarker(img, (int(o[0]), int(o[1])), (0, 0, 0), cv2.MARKER_CROSS, 12, 1)
    _legend(img, walk is not None)
    return _png(img)


def half_cell(floors: Sequence[ZoneFloor]) -> float:
    return floors[0].cell_m / 2 if floors else 0.125


def camera_picture(image_bgr: np.ndarray, cell: Cell, camera_id: str,
                   floors: Sequence[ZoneFloor], walk: WalkResult | None) -> bytes:
    """PNG: the camera's image with its zones, the seen cells (green dots) and the blind spots
    (red crosses) where the camera model places them."""
    img = draw_zones(image_bgr, cell, camera_id, legend=False)
    model = cell.camera_models.get(camera_id)
    if model is not None:
        cam = cell.cameras[camera_id]
        scale = np.array([img.shape[1] / model.width, img.shape[0] / model.height])
        unvisited = {}
        if walk is not None:
            unvisited = {z.zone_id: set(z.unvisited) for z in walk.zones}
        for f in floors:
            px, front = model.project(np.c_[f.centres_m, np.zeros(len(f.centres_m))])
            px = px * scale
            for c, p, ok, vis in zip(f.centres_m, px, front, f.visible, strict=True):
                if not ok or not (0 <= p[0] < cam.width and 0 <= p[1] < cam.height):
                    continue
                q = (round(float(p[0])), round(float(p[1])))
                key = (round(float(c[0]), 3), round(float(c[1]), 3))
                if not vis:
                    cv2.drawMarker(img, q, BLIND_BGR, cv2.MARKER_TILTED_CROSS, 8, 2)
                elif f.zone_id in unvisited and key not in unvisited[f.zone_id]:
                    cv2.circle(img, q, 3, SEEN_BGR, -1)
    return _png(img)


def _legend(img: np.ndarray, walked: bool) -> None:
    y = img.shape[0] - 10
    x = 8
    keys = (("seen in the walk", SEEN_BGR), ("visible, not walked", UNVISITED_BGR)) if walked \
        else (("visible to a camera", UNVISITED_BGR),)
    for text, colour in (*keys, ("blind spot", BLIND_BGR)):
        cv2.rectangle(img, (x, y - 10), (x + 12, y + 2), colour, -1)
        cv2.putText(img, text, (x + 16, y), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1,
                    cv2.LINE_AA)
        x += 30 + 8 * len(text)


def _png(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError("cannot encode a PNG")
    return buf.tobytes()
