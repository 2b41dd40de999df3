"""Sight lines against occluder volumes, exactly: does the segment from the camera to a point
pass through a box, a prism or a cylinder?

Sampling the line (32 or 48 points, then a containment test) misses every occluder thinner
than the gap between two samples: from a camera 6 m away a sample every 18 cm, so a 3 cm
sheet-metal screen 2.2 m tall hid nothing of the floor behind it (157 of 205 floor points
behind it were "seen", issue 46's assessor round, 2026-12-03). Here each shape is
intersected with the segment in closed form (slabs for boxes, the quadratic for cylinders,
edge crossings for prisms, Moller-Trumbore against each triangle of a mesh).

A segment is ``origin + t (end - origin)`` for ``t`` in ``[t0, t1]`` (the ends excluded by
the caller's choice of ``t0 > 0`` and ``t1 < 1``: a point on an occluder's face is not hidden
by it). Touching a face counts as passing through (as ``points_in_volume`` counts a point on
a face as inside). Pure numpy.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from monitor.geometry.polygons import points_in_polygon
from monitor.geometry.poses import rpy_to_matrix
from monitor.geometry.shapes import points_in_mesh

_EPS = 1e-12


def _slab(a: np.ndarray, d: np.ndarray, lo: float, hi: float
          ) -> tuple[np.ndarray, np.ndarray]:
    """The t interval (enter, leave) where ``a + t d`` lies in [lo, hi], per line (enter >
    leave: never)."""
    flat = np.abs(d) < _EPS
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - a) / d
        tb = (hi - a) / d
    enter = np.where(flat, np.where((a >= lo) & (a <= hi), -np.inf, np.inf), np.minimum(ta, tb))
    leave = np.where(flat, np.where((a >= lo) & (a <= hi), np.inf, -np.inf), np.maximum(ta, tb))
    return enter, leave


def _box(z, a: np.ndarray, d: np.ndarray, t0: float, t1: float) -> np.ndarray:
    lo, hi = np.asarray(z.min_m, float), np.asarray(z.max_m, float)
    c = (lo + hi) / 2
    rot = rpy_to_matrix(0, 0, z.yaw_deg)[:2, :2]
    la = (a[:, :2] - c[:2]) @ rot  # into the box frame, as points_in_volume turns points
    ld = d[:, :2] @ rot
    half = (hi - lo)[:2] / 2
    enter, leave = np.full(len(a), t0), np.full(len(a), t1)
    for axis in range(2):
        e, lv = _slab(la[:, axis], ld[:, axis], -half[axis], half[axis])
        enter, leave = np.maximum(enter, e), np.minimum(leave, lv)
    e, lv = _slab(a[:, 2], d[:, 2], lo[2], hi[2])
    return np.maximum(enter, e) <= np.minimum(leave, lv)


def _cylinder(z, a: np.ndarray, d: np.ndarray, t0: float, t1: float) -> np.ndarray:
    c = np.asarray(z.center_m, float)[:2]
    p = a[:, :2] - c
    qa = np.einsum("ij,ij->i", d[:, :2], d[:, :2])
    qb = 2.0 * np.einsum("ij,ij->i", p, d[:, :2])
    qc = np.einsum("ij,ij->i", p, p) - float(z.radius_m) ** 2
    flat = qa < _EPS
    disc = qb * qb - 4.0 * qa * qc
    root = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        enter = np.where(flat, np.where(qc <= 0, -np.inf, np.inf), (-qb - root) / (2 * qa))
        leave = np.where(flat, np.where(qc <= 0, np.inf, -np.inf), (-qb + root) / (2 * qa))
    enter = np.where(~flat & (disc < 0), np.inf, enter)
    e, lv = _slab(a[:, 2], d[:, 2], float(z.z_min_m), float(z.z_max_m))
    return np.maximum.reduce([enter, e, np.full(len(a), t0)]) \
        <= np.minimum.reduce([leave, lv, np.full(len(a), t1)])


def _prism(polygon: np.ndarray, z_lo: float, z_hi: float, a: np.ndarray, d: np.ndarray,
           t0: float, t1: float) -> np.ndarray:
    """A vertical prism over ``polygon`` (K, 2), any simple polygon (convex or not)."""
    e, lv = _slab(a[:, 2], d[:, 2], z_lo, z_hi)
    ta, tb = np.maximum(e, t0), np.minimum(lv, t1)
    out = ta <= tb
    idx = np.flatnonzero(out)
    if not len(idx):
        return out
    p0 = a[idx, :2] + ta[idx, None] * d[idx, :2]  # the part of the line within the heights
    p1 = a[idx, :2] + tb[idx, None] * d[idx, :2]
    hit = points_in_polygon(p0, polygon)  # starts inside (or lies wholly inside)
    q0 = np.asarray(polygon, float)
    q1 = np.roll(q0, -1, axis=0)
    r = (p1 - p0)[:, None, :]  # (n, 1, 2) against every edge (1, k, 2)
    s = (q1 - q0)[None, :, :]
    w = q0[None, :, :] - p0[:, None, :]
    denom = r[..., 0] * s[..., 1] - r[..., 1] * s[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (w[..., 0] * s[..., 1] - w[..., 1] * s[..., 0]) / denom
        v = (w[..., 0] * r[..., 1] - w[..., 1] * r[..., 0]) / denom
    crosses = (np.abs(denom) > _EPS) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    out[idx] = hit | crosses.any(axis=1)
    return out


def _mesh(verts: np.ndarray, faces: np.ndarray, a: np.ndarray, d: np.ndarray,
          t0: float, t1: float, chunk: int = 4096) -> np.ndarray:
    """A closed triangle mesh: the line starts inside it, or crosses one of its triangles
    within [t0, t1] (Moller-Trumbore against every triangle, for the lines that cross the
    mesh's bounding box; in chunks of lines, so a big mesh never needs lines x triangles of
    memory at once)."""
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    enter, leave = np.full(len(a), t0), np.full(len(a), t1)
    for axis in range(3):
        e, lv = _slab(a[:, axis], d[:, axis], lo[axis], hi[axis])
        enter, leave = np.maximum(enter, e), np.minimum(leave, lv)
    out = enter <= leave
    idx = np.flatnonzero(out)
    if not len(idx):
        return out
    tri = verts[faces]
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    hit = np.zeros(len(idx), bool)
    step = max(1, chunk * 64 // max(len(faces), 1))
    for k in range(0, len(idx), step):
        rows = idx[k:k + step]
        hit[k:k + step] = points_in_mesh(a[rows] + t0 * d[rows], verts, faces)  # starts inside
        dd, aa = d[rows][:, None, :], a[rows][:, None, :]
        pvec = np.cross(dd, e2[None])
        det = np.einsum("nij,ij->ni", pvec, e1)
        ok = np.abs(det) > _EPS
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tvec = aa - v0[None]
        u = np.einsum("nij,nij->ni", tvec, pvec) * inv
        qvec = np.cross(tvec, e1[None])
        v = np.einsum("nij,nij->ni", np.broadcast_to(dd, qvec.shape), qvec) * inv
        t = np.einsum("ij,nij->ni", e2, qvec) * inv
        cross = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= t0) & (t <= t1)
        hit[k:k + step] |= cross.any(axis=1)
    out[idx] = hit
    return out


def segment_through(z, origin: np.ndarray, ends: np.ndarray, t0: float, t1: float,
                    meshes: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """(N,) bool: the segments from ``origin`` (3,) to ``ends`` (N, 3), for t in [t0, t1],
    pass through the volume zone spec ``z`` (box, extrude, cylinder, mesh)."""
    b = np.asarray(ends, float).reshape(-1, 3)
    a = np.broadcast_to(np.asarray(origin, float).reshape(1, 3), b.shape)
    d = b - a
    if not len(b):
        return np.zeros(0, bool)
    if z.shape == "box":
        return _box(z, a, d, t0, t1)
    if z.shape == "cylinder":
        return _cylinder(z, a, d, t0, t1)
    if z.shape == "extrude":
        return _prism(np.asarray(z.points_m, float), float(z.z_min_m), float(z.z_max_m),
                      a, d, t0, t1)
    verts, faces = meshes[z.id]
    return _mesh(np.asarray(verts, float), np.asarray(faces), a, d, t0, t1)


def sight_blocked(occluders: Sequence, meshes: Mapping[str, tuple[np.ndarray, np.ndarray]],
                  origin: np.ndarray, ends: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """(N,) bool: the segments pass through any of ``occluders``."""
    b = np.asarray(ends, float).reshape(-1, 3)
    out = np.zeros(len(b), bool)
    for z in occluders:
        left = np.flatnonzero(~out)
        if not len(left):
            break
        out[left] = segment_through(z, origin, b[left], t0, t1, meshes)
    return out


__all__ = ["segment_through", "sight_blocked"]
