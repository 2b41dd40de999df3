"""The unseen regions of the protective and warning zones, for the commissioning report: floor
no camera sees a person on (``floor.visible_cells``, the map a lost person's area is judged
by), each connected region with what it costs and what would see it.

* **Cost in availability**: a lost person's area that reaches such a region is never seen free
  there, so the cell stays held until a second camera sees it or an operator confirms the cell
  clear. The report gives its floor area (m^2) and its share of the zone's floor: the larger,
  the more often a person walking the zone is lost into it.
* **What hides it**: the occluder that, taken away, would let the cameras see most of it, or
  "outside every camera's picture".
* **A camera that would see it**: candidate positions around the region (``DIRECTIONS`` at
  ``DISTANCES_M``, at the height of the highest calibrated camera, looking at the region's
  middle with that camera's lens and image size), each judged with the same visibility test
  the monitor uses (``monitor.zones.coverage.figure_visible`` past every occluder, the feet in
  the image); the one that sees most of the region is suggested, with the side it looks from.

Pure: a loaded ``Cell`` in, JSON-able dicts out (rounded: the report is deterministic).
"""

from __future__ import annotations

import math

import numpy as np

from monitor import geometry as geo
from monitor.commission.floor import ZoneFloor, zone_floors
from monitor.geometry.occlusion import camera_centre_m
from monitor.zones import Cell, volume_outline_m
from monitor.zones.coverage import figure_visible, occluders_contain

DISTANCES_M = (3.0, 4.5)
DIRECTIONS = 8  # compass directions around the region


def _regions(floor: ZoneFloor) -> list[np.ndarray]:
    """Indices (into the zone's cells) of each 8-connected group of unseen cells."""
    blind = np.flatnonzero(~floor.visible)
    where = {(int(floor.index[k, 0]), int(floor.index[k, 1])): int(k) for k in blind}
    out, done = [], set()
    for start in where:
        if start in done:
            continue
        group, todo = [], [start]
        done.add(start)
        while todo:
            r, c = todo.pop()
            group.append(where[(r, c)])
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    n = (r + dr, c + dc)
                    if n in where and n not in done:
                        done.add(n)
                        todo.append(n)
        out.append(np.array(sorted(group)))
    return sorted(out, key=lambda g: (-len(g), int(g[0])))


def _side(d: np.ndarray) -> str:
    """The side a direction (x right, y up) points to, in the cell's own axes."""
    names = ["+x", "+x +y", "+y", "-x +y", "-x", "-x -y", "-y", "+x -y"]
    angle = math.degrees(math.atan2(float(d[1]), float(d[0]))) % 360.0
    return names[int(((angle + 22.5) % 360.0) // 45.0)]


def _look_at(position: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t (cell -> camera) of a camera at ``position`` looking at ``target`` (z up)."""
    forward = target - position
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward])
    return rotation, -rotation @ position


def _seen_by(model: geo.CameraModel, feet: np.ndarray, cell: Cell, contain) -> np.ndarray:
    """(N,) bool: ``model`` sees a person of the smallest height standing on each point."""
    p = cell.spec.person
    px, front = model.project(np.c_[feet, np.zeros(len(feet))])
    inside = front & np.all(np.isfinite(px), axis=1) & (px[:, 0] >= 0) \
        & (px[:, 0] < model.width) & (px[:, 1] >= 0) & (px[:, 1] < model.height)
    return inside & figure_visible(model, feet, p.smallest_height_m, p.needed_fraction,
                                   p.radius_m, contain)


def _template(cell: Cell) -> tuple[geo.CameraModel, float] | None:
    """The calibrated pinhole camera mounted highest (its lens, size and height are the
    suggestion's); None when no camera can project heights."""
    best = None
    for model in cell.camera_models.values():
        centre = camera_centre_m(model)
        if centre is None or model.camera_matrix is None:
            continue
        if best is None or centre[2] > best[1]:
            best = (model, float(centre[2]))
    return best


def _suggest(cell: Cell, feet: np.ndarray, hidden_by: np.ndarray | None, contain
             ) -> dict | None:
    """The candidate camera that sees most of ``feet`` (ties: looking from the side facing
    away from the occluder, then the nearer); None without a camera to copy."""
    template = _template(cell)
    if template is None or not len(feet):
        return None
    base, height = template
    middle = feet.mean(axis=0)
    target = np.r_[middle, 0.0]
    best = None
    for distance in DISTANCES_M:
        for k in range(DIRECTIONS):
            a = 2 * math.pi * k / DIRECTIONS
            d = np.array([math.cos(a), math.sin(a)])
            position = np.r_[middle + distance * d, height]
            rotation, t = _look_at(position, target)
            model = geo.CameraModel.pinhole(base.width, base.height, base.camera_matrix, None,
                                            rotation, t)
            share = float(_seen_by(model, feet, cell, contain).mean())
            away = 0.0 if hidden_by is None else -float(np.dot(d, hidden_by - middle))
            key = (round(share, 3), away, -distance)
            if best is None or key > best[0]:
                best = (key, position, d, share)
    assert best is not None
    _, position, d, share = best
    return {"position_m": [round(float(v), 2) for v in position],
            "looking_at_m": [round(float(v), 2) for v in middle], "from_side": _side(d),
            "sees_share": round(share, 3)}


def _hidden_by(cell: Cell, feet: np.ndarray) -> tuple[str, np.ndarray | None]:
    """What hides ``feet`` from every camera: the occluder that, taken away, would let the
    cameras see most of them (its footprint's middle too), else why none does."""
    occluders = cell.spec.occluder_zones()
    models = [m for m in cell.camera_models.values() if m.can_project_3d]

    def seen(contain) -> np.ndarray:
        out = np.zeros(len(feet), dtype=bool)
        for model in models:
            out |= _seen_by(model, feet, cell, contain)
        return out

    now = seen(occluders_contain(occluders, cell.meshes))
    best: tuple[float, str, np.ndarray] | None = None
    for z in occluders:
        others = [o for o in occluders if o.id != z.id]
        gain = float((seen(occluders_contain(others, cell.meshes)) & ~now).mean())
        if gain > 0 and (best is None or gain > best[0]):
            outline = np.concatenate(volume_outline_m(z, cell))[:, :2]
            best = (gain, z.id, outline.mean(axis=0))
    if best is not None:
        return f"behind {best[1]}", best[2]
    if not seen(lambda pts: np.zeros(len(pts), dtype=bool)).any():
        return "outside every camera's picture", None
    return "in a mask zone, or where the zone file declares nothing that hides it", None


def unseen_regions(cell: Cell) -> list[dict]:
    """Every unseen region of every enabled protective and warning volume zone (file order,
    the largest region first): zone, kind, cells, floor area (m^2), share of the zone's floor,
    middle (m), what hides it, and a camera that would see it."""
    contain = occluders_contain(cell.spec.occluder_zones(), cell.meshes)
    out = []
    for floor in zone_floors(cell):
        total = len(floor.centres_m)
        for group in _regions(floor):
            feet = floor.centres_m[group]
            hidden_by, centre = _hidden_by(cell, feet)
            out.append({
                "zone": floor.zone_id, "kind": floor.kind, "cells": len(group),
                "area_m2": round(len(group) * floor.cell_m ** 2, 2),
                "share": round(len(group) / max(total, 1), 3),
                "middle_m": [round(float(v), 2) for v in feet.mean(axis=0)],
                "hidden_by": hidden_by,
                "camera": _suggest(cell, feet, centre, contain)})
    return out
