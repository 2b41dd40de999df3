"""FCL helpers: collision objects of boxes, cylinders, prisms and meshes; point-in-mesh."""

from __future__ import annotations

from collections.abc import Sequence

import fcl
import numpy as np

from monitor.geometry.polygons import is_convex, polygon_signed_area, triangulate_polygon
from monitor.geometry.poses import rpy_to_matrix


def fcl_box(min_m: Sequence[float], max_m: Sequence[float], yaw_deg: float = 0.0
            ) -> fcl.CollisionObject:
    """A box from its min/max corners, turned by ``yaw_deg`` about the vertical through its
    centre."""
    lo, hi = np.asarray(min_m, dtype=float), np.asarray(max_m, dtype=float)
    size = hi - lo
    tf = fcl.Transform(rpy_to_matrix(0, 0, yaw_deg), (lo + hi) / 2)
    return fcl.CollisionObject(fcl.Box(*size), tf)


def fcl_vertical_cylinder(center_xy_m: Sequence[float], radius_m: float, z_min_m: float,
                          z_max_m: float) -> fcl.CollisionObject:
    cx, cy = (float(v) for v in center_xy_m)
    geom = fcl.Cylinder(float(radius_m), float(z_max_m - z_min_m))
    return fcl.CollisionObject(geom, fcl.Transform(np.array([cx, cy, (z_min_m + z_max_m) / 2])))


def fcl_prism_parts(points_m: np.ndarray, z_min_m: float, z_max_m: float
                    ) -> list[fcl.CollisionObject]:
    """A floor polygon extruded from z_min to z_max as convex fcl solids (one when the polygon
    is convex, else one triangular prism per ear), so that containment counts as overlap."""
    return [fcl.CollisionObject(g, fcl.Transform())
            for g in prism_geometries(points_m, z_min_m, z_max_m)]


def prism_geometries(points_m: np.ndarray, z_min_m: float, z_max_m: float) -> list[fcl.Convex]:
    """The convex solids of ``fcl_prism_parts`` as geometries (in the polygon's own frame), for
    volumes that are placed anew at every step (zones that follow the tool)."""
    p = np.asarray(points_m, dtype=float)
    if polygon_signed_area(p) < 0:
        p = p[::-1]
    pieces = [p] if is_convex(p) else [p[t] for t in triangulate_polygon(p)]
    return [_convex_prism(q, z_min_m, z_max_m) for q in pieces]


def _convex_prism(poly: np.ndarray, z0: float, z1: float) -> fcl.Convex:
    n = len(poly)
    verts = np.vstack([np.c_[poly, np.full(n, z0)], np.c_[poly, np.full(n, z1)]])
    faces: list[int] = [n, *range(n - 1, -1, -1), n, *range(n, 2 * n)]
    for k in range(n):
        m = (k + 1) % n
        faces += [4, k, m, n + m, n + k]
    return fcl.Convex(verts, n + 2, np.array(faces, dtype=np.int64))


def fcl_mesh(vertices: np.ndarray, faces: np.ndarray) -> fcl.CollisionObject:
    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(faces))
    model.addSubModel(np.asarray(vertices, dtype=float), np.asarray(faces, dtype=np.int64))
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


def points_in_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Which (N, 3) points are inside a closed triangle mesh: parity of crossings along a ray
    (Moller-Trumbore, vectorised). The ray direction is slightly skewed to avoid edges."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    tri = np.asarray(vertices, dtype=float)[np.asarray(faces)]
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    direction = np.array([0.5773, 0.5774, 0.5775])
    h = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = pts[:, None, :] - v0[None]
    u = np.einsum("nij,ij->ni", s, h) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("k,nik->ni", direction, q) * inv
    t = np.einsum("ij,nij->ni", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return (hit.sum(axis=1) % 2) == 1

