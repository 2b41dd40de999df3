"""Zone volumes as the per-frame checks use them: a volume's FCL parts and bounds, built
once (``prepare_volume``), and the test of a person's swept cylinder against one
(``swept_person``, ``overlaps``). Shared by the fixed zones (``prepare``, ``check``) and the
zones that follow the tool (``moving_check``), below all three so that none imports another
to reach them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import fcl
import numpy as np

from monitor import geometry as geo
from monitor.geometry import occlusion as occ
from monitor.zones.schema import BoxZone, CylinderZone, ExtrudeZone
from monitor.zones.views import CellData, PreparedData

FCL_DISTANCE_MARGIN_M = 0.0005

_REQ = fcl.CollisionRequest()


@dataclass(frozen=True, eq=False)
class Volume:
    id: str
    kind: str
    speed_scale: float
    parts: tuple[fcl.CollisionObject, ...]
    lo: np.ndarray  # axis-aligned bounds, metres
    hi: np.ndarray
    mesh: tuple[np.ndarray, np.ndarray] | None  # closed mesh: containment needs a ray test


def zone_scale(z: Any) -> float:
    return float(z.speed_scale) if z.kind == "warning" and z.speed_scale is not None else 0.0


def box_corners(z: BoxZone) -> np.ndarray:
    lo, hi = np.array(z.min_m), np.array(z.max_m)
    c = (lo + hi) / 2
    half = (hi - lo) / 2
    sx, sy = half[0], half[1]
    base = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]])
    rot = geo.rpy_to_matrix(0, 0, z.yaw_deg)[:2, :2]
    xy = base @ rot.T + c[:2]
    return np.r_[np.c_[xy, np.full(4, lo[2])], np.c_[xy, np.full(4, hi[2])]]


def occluder_corners_m(z: Any, cell: CellData, segments: int = 24) -> np.ndarray:
    """Points (M, 3) whose convex hull contains a volume (corners; a cylinder's rims)."""
    if isinstance(z, ExtrudeZone):
        base = np.array(z.points_m, dtype=float)
        return np.r_[np.c_[base, np.full(len(base), z.z_min_m)],
                     np.c_[base, np.full(len(base), z.z_max_m)]]
    if isinstance(z, BoxZone):
        return box_corners(z)
    if isinstance(z, CylinderZone):
        a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
        # the polygon's corners lie outside the circle, so the hull contains it
        r = z.radius_m / np.cos(np.pi / segments)
        ring = np.c_[z.center_m[0] + r * np.cos(a), z.center_m[1] + r * np.sin(a)]
        return np.r_[np.c_[ring, np.full(segments, z.z_min_m)],
                     np.c_[ring, np.full(segments, z.z_max_m)]]
    return np.asarray(cell.meshes[z.id][0], dtype=float)


def prepare_volume(z: Any, cell: CellData) -> Volume:
    mesh = None
    if isinstance(z, ExtrudeZone):
        pts = np.array(z.points_m, dtype=float)
        parts = geo.fcl_prism_parts(pts, z.z_min_m, z.z_max_m)
        lo = np.r_[pts.min(axis=0), z.z_min_m]
        hi = np.r_[pts.max(axis=0), z.z_max_m]
    elif isinstance(z, BoxZone):
        parts = [geo.fcl_box(z.min_m, z.max_m, z.yaw_deg)]
        corners = box_corners(z)
        lo, hi = corners.min(axis=0), corners.max(axis=0)
    elif isinstance(z, CylinderZone):
        parts = [geo.fcl_vertical_cylinder(z.center_m, z.radius_m, z.z_min_m, z.z_max_m)]
        c = np.array(z.center_m)
        lo = np.r_[c - z.radius_m, z.z_min_m]
        hi = np.r_[c + z.radius_m, z.z_max_m]
    else:
        mesh = cell.meshes[z.id]
        parts = [geo.fcl_mesh(*mesh)]
        lo, hi = mesh[0].min(axis=0), mesh[0].max(axis=0)
    return Volume(z.id, z.kind, zone_scale(z), tuple(parts), np.asarray(lo, float),
                   np.asarray(hi, float), mesh)


def stand_span(place: occ.Placement, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(N,) lowest foot and highest head of each person over every surface their range may
    put them on (the cell floor, declared floor regions)."""
    n = len(place.located)
    lo = place.stand_lo_m if place.stand_lo_m is not None else np.zeros(n)
    hi = place.stand_hi_m if place.stand_hi_m is not None else np.zeros(n)
    return np.minimum(lo, 0.0), np.maximum(hi, 0.0) + height_m


def swept_person(prep: PreparedData, a: np.ndarray, b: np.ndarray, z0: float = 0.0,
                  z1: float | None = None) -> list[fcl.CollisionObject]:
    """The zone cylinder swept from floor point ``a`` to ``b``: one cylinder, or a box between
    two end cylinders (exactly the swept volume); from ``z0`` to ``z1`` (the person height
    over the floor by default; taller over floor regions)."""
    r, h = prep.person.zone_radius_m, prep.person.height_m
    span = h if z1 is None else z1 - z0
    cyl = prep.zone_cylinder if z0 == 0.0 and span == h else fcl.Cylinder(r, span)
    zc = z0 + span / 2
    d = b - a
    length = float(np.hypot(*d))
    ends = [np.array((a[0], a[1], zc))]
    if length < 1e-4:
        return [fcl.CollisionObject(cyl, fcl.Transform(ends[0]))]
    ends.append(np.array((b[0], b[1], zc)))
    c, s = d[0] / length, d[1] / length  # turn the box's x axis onto the segment
    rot = np.array(((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)))
    mid = np.array(((a[0] + b[0]) / 2, (a[1] + b[1]) / 2, zc))
    objs = [fcl.CollisionObject(fcl.Box(length, 2 * r, span), fcl.Transform(rot, mid))]
    objs += [fcl.CollisionObject(cyl, fcl.Transform(e)) for e in ends]
    return objs


def overlaps(objs: list[fcl.CollisionObject], v: Volume, a: np.ndarray, b: np.ndarray,
              r: float, h: float, z0: float = 0.0) -> bool:
    for obj in objs:
        for part in v.parts:
            if fcl.collide(obj, part, _REQ, fcl.CollisionResult()):
                return True
    if v.mesh is None:
        return False
    # FCL tests mesh surfaces only: with no surface contact the swept cylinder is wholly
    # inside or wholly outside the closed mesh (or the mesh is inside the swept cylinder)
    if geo.points_in_mesh(np.r_[a, z0 + h / 2][None], *v.mesh)[0]:
        return True
    p = v.mesh[0][0]
    return bool(_point_segment_distance(p[:2], a, b) <= r and z0 <= p[2] <= z0 + h)


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    d = b - a
    den = float(d @ d)
    t = 0.0 if den == 0 else min(max(float((p - a) @ d) / den, 0.0), 1.0)
    return float(np.hypot(*(a + t * d - p)))
