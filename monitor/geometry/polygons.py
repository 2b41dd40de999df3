"""Polygons (image pixels or floor metres; both are plain 2-D here): point tests, faults,
triangulation, clipping."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monitor.geometry.errors import GeometryError


def polygon_signed_area(polygon: np.ndarray) -> float:
    """Shoelace area; positive when the points run counter-clockwise in a y-up frame."""
    p = np.asarray(polygon, dtype=float)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd rule: which of the (N, 2) points lie inside the (K, 2) polygon; (N,) bool.

    Points exactly on an edge may fall either way (as with any floating-point test).
    """
    return points_in_polygons(points, [polygon])[:, 0]


def points_in_polygons(points: np.ndarray, polygons: Sequence[np.ndarray]) -> np.ndarray:
    """Even-odd rule for many polygons at once, one vectorised pass; (N, Z) bool."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    edges = PolygonEdges.build(polygons)
    return edges.contains(pts)


@dataclass(frozen=True)
class PolygonEdges:
    """All edges of several polygons, stacked, so that a point test is one numpy pass."""

    x0: np.ndarray
    y0: np.ndarray
    dx_dy: np.ndarray  # (x1 - x0) / (y1 - y0), 0 where the edge is horizontal
    ylo: np.ndarray
    yhi: np.ndarray
    starts: np.ndarray  # index of the first edge of each polygon
    count: int

    @classmethod
    def build(cls, polygons: Sequence[np.ndarray]) -> PolygonEdges:
        if not polygons:
            z = np.zeros(0)
            return cls(z, z, z, z, z, np.zeros(0, dtype=np.intp), 0)
        p0 = [np.asarray(p, dtype=float).reshape(-1, 2) for p in polygons]
        a = np.concatenate(p0)
        b = np.concatenate([np.roll(p, -1, axis=0) for p in p0])
        dy = b[:, 1] - a[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = np.where(dy != 0, (b[:, 0] - a[:, 0]) / np.where(dy != 0, dy, 1), 0.0)
        starts = np.cumsum([0] + [len(p) for p in p0[:-1]]).astype(np.intp)
        return cls(
            a[:, 0], a[:, 1], slope, np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1]),
            starts, len(p0),
        )

    def contains(self, pts: np.ndarray) -> np.ndarray:
        if self.count == 0 or len(pts) == 0:
            return np.zeros((len(pts), self.count), dtype=bool)
        px = pts[:, 0:1]
        py = pts[:, 1:2]
        # half-open rule on y (ylo <= y < yhi) so a vertex is counted once
        spans = (self.ylo <= py) & (py < self.yhi)
        x_cross = self.x0 + (py - self.y0) * self.dx_dy
        crossings = (spans & (px < x_cross)).astype(np.int32)
        return (np.add.reduceat(crossings, self.starts, axis=1) & 1).astype(bool)


def polygon_fault(points: Sequence[Sequence[float]]) -> str | None:
    """Why a polygon is unusable (fewer than 3 points, repeated points, zero area,
    self-intersection), or None when it is a simple polygon."""
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2:
        return "points must be pairs x,y"
    n = len(p)
    if n < 3:
        return f"polygon needs at least 3 points, got {n}"
    if not np.all(np.isfinite(p)):
        return "polygon has a non-finite coordinate"
    scale = max(float(np.ptp(p[:, 0])), float(np.ptp(p[:, 1])), 1e-12)
    eps = 1e-9 * scale
    for i in range(n):
        for j in range(i + 1, n):
            if np.all(np.abs(p[i] - p[j]) <= eps):
                if i == 0 and j == n - 1:
                    return f"last point repeats the first (do not close the ring; point {n})"
                return f"degenerate polygon: point {j + 1} repeats point {i + 1}"
    spread = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    if spread[1] <= 1e-9 * max(spread[0], 1e-300):
        return "degenerate polygon: all points on one line"
    crossing = _first_self_intersection(p, eps)
    if crossing is not None:
        i, j = crossing
        return (
            f"self-intersecting polygon: edge {_edge_name(i, n)} crosses or touches edge "
            f"{_edge_name(j, n)}"
        )
    if abs(polygon_signed_area(p)) <= 1e-9 * scale * scale:
        return "degenerate polygon: zero area"
    return None


def _edge_name(i: int, n: int) -> str:
    """Edge i joins point i+1 to the next point (1-based, as a user counts them)."""
    return f"{i + 1}-{(i + 1) % n + 1}"


def _orient(ax, ay, bx, by, cx, cy):
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


def _first_self_intersection(p: np.ndarray, eps: float) -> tuple[int, int] | None:
    """First pair of edges (i, j) that cross or touch, other than neighbours sharing a vertex.

    Neighbouring edges only count when they fold back onto each other (a spike).
    """
    n = len(p)
    a = p
    b = np.roll(p, -1, axis=0)
    i, j = np.triu_indices(n, k=1)
    ax, ay, bx, by = a[i, 0], a[i, 1], b[i, 0], b[i, 1]
    cx, cy, dx, dy = a[j, 0], a[j, 1], b[j, 0], b[j, 1]
    o1 = _orient(ax, ay, bx, by, cx, cy)
    o2 = _orient(ax, ay, bx, by, dx, dy)
    o3 = _orient(cx, cy, dx, dy, ax, ay)
    o4 = _orient(cx, cy, dx, dy, bx, by)
    tol = eps * max(1.0, float(np.abs(p).max()))
    s1, s2, s3, s4 = (np.where(np.abs(o) <= tol, 0, np.sign(o)) for o in (o1, o2, o3, o4))

    def on_segment(px_, py_, qx, qy, rx, ry):
        # r on segment p-q, given the three are collinear
        return (
            (np.minimum(px_, qx) - eps <= rx) & (rx <= np.maximum(px_, qx) + eps)
            & (np.minimum(py_, qy) - eps <= ry) & (ry <= np.maximum(py_, qy) + eps)
        )

    proper = (s1 * s2 < 0) & (s3 * s4 < 0)
    touch = (
        ((s1 == 0) & on_segment(ax, ay, bx, by, cx, cy))
        | ((s2 == 0) & on_segment(ax, ay, bx, by, dx, dy))
        | ((s3 == 0) & on_segment(cx, cy, dx, dy, ax, ay))
        | ((s4 == 0) & on_segment(cx, cy, dx, dy, bx, by))
    )
    neighbours = (j == i + 1) | ((i == 0) & (j == n - 1))
    # neighbours share one vertex; they only conflict when collinear and folding back
    e1 = np.stack([bx - ax, by - ay], axis=1)
    e2 = np.stack([dx - cx, dy - cy], axis=1)
    fold = (s1 == 0) & (s2 == 0) & (np.einsum("ij,ij->i", e1, e2) < 0)
    bad = np.where(neighbours, fold, proper | touch)
    if not bad.any():
        return None
    k = int(np.argmax(bad))
    return int(i[k]), int(j[k])


def triangulate_polygon(polygon: np.ndarray) -> np.ndarray:
    """Ear-clipping triangulation of a simple polygon; (T, 3) vertex indices, counter-clockwise
    in a y-up frame. Collinear vertices are skipped (they add no area)."""
    p = np.asarray(polygon, dtype=float)
    idx = list(range(len(p)))
    if polygon_signed_area(p) < 0:
        idx.reverse()
    tol = 1e-12 * max(float(np.abs(p).max()), 1.0) ** 2

    def cross(a: int, b: int, c: int) -> float:
        return float(_orient(p[a, 0], p[a, 1], p[b, 0], p[b, 1], p[c, 0], p[c, 1]))

    # drop collinear vertices first: they would never be ears
    changed = True
    while changed and len(idx) > 3:
        changed = False
        for k in range(len(idx)):
            if abs(cross(idx[k - 1], idx[k], idx[(k + 1) % len(idx)])) <= tol:
                idx.pop(k)
                changed = True
                break
    triangles: list[tuple[int, int, int]] = []
    while len(idx) > 3:
        m = len(idx)
        for k in range(m):
            a, b, c = idx[k - 1], idx[k], idx[(k + 1) % m]
            if cross(a, b, c) <= tol:
                continue  # reflex corner
            others = [v for v in idx if v not in (a, b, c)]
            if others:
                q = p[others]
                inside = (
                    (_orient(p[a, 0], p[a, 1], p[b, 0], p[b, 1], q[:, 0], q[:, 1]) >= -tol)
                    & (_orient(p[b, 0], p[b, 1], p[c, 0], p[c, 1], q[:, 0], q[:, 1]) >= -tol)
                    & (_orient(p[c, 0], p[c, 1], p[a, 0], p[a, 1], q[:, 0], q[:, 1]) >= -tol)
                )
                if inside.any():
                    continue
            triangles.append((a, b, c))
            idx.pop(k)
            break
        else:
            raise GeometryError("polygon cannot be triangulated (not simple)")
    triangles.append((idx[0], idx[1], idx[2]))
    return np.array(triangles, dtype=np.intp)


def is_convex(polygon: np.ndarray) -> bool:
    """True when every corner of the simple polygon turns the same way."""
    p = np.asarray(polygon, dtype=float)
    a, b, c = np.roll(p, 1, axis=0), p, np.roll(p, -1, axis=0)
    z = _orient(a[:, 0], a[:, 1], b[:, 0], b[:, 1], c[:, 0], c[:, 1])
    return bool(np.all(z >= 0) or np.all(z <= 0))


def clip_polygon_to_rect(polygon: np.ndarray, width: float, height: float) -> np.ndarray:
    """Sutherland-Hodgman clip of a polygon to the image rectangle [0, width] x [0, height].

    Returns (K, 2) float64, possibly empty (K = 0) when nothing of the polygon is inside.
    """
    out = [tuple(map(float, q)) for q in np.asarray(polygon, dtype=float).reshape(-1, 2)]
    for axis, limit, keep_below in ((0, 0.0, False), (0, width, True), (1, 0.0, False),
                                    (1, height, True)):
        if not out:
            break
        src, out = out, []

        def inside(q, axis=axis, limit=limit, keep_below=keep_below):
            return q[axis] <= limit if keep_below else q[axis] >= limit

        for k, cur in enumerate(src):
            prev = src[k - 1]
            if inside(cur):
                if not inside(prev):
                    out.append(_cut(prev, cur, axis, limit))
                out.append(cur)
            elif inside(prev):
                out.append(_cut(prev, cur, axis, limit))
    return np.array(out, dtype=float).reshape(-1, 2)


def _cut(p, q, axis, limit):
    t = (limit - p[axis]) / (q[axis] - p[axis])
    x = p[0] + t * (q[0] - p[0])
    y = p[1] + t * (q[1] - p[1])
    return (limit, y) if axis == 0 else (x, limit)

