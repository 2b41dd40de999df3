"""Geometry for the zone checks: polygons, camera models, person cylinders, tool pose, ISO/TS 15066.

Pure functions over numpy arrays; nothing here reads files or keeps state.

Frames and units:

* image: pixels of one camera at its full resolution, x right, y down, origin at the top-left
  corner of the top-left pixel (``*_px``);
* cell: metres, z up, origin at the robot base on the floor (``*_m``);
* camera: OpenCV convention, x right, y down, z forward; ``x_cam = R @ x_cell + t``.

Python-fcl does the 3-D overlap and distance tests; the helpers that build its objects are here so
that tests can check them against closed-form distances.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import fcl
import numpy as np

__all__ = [
    "CameraModel",
    "GeometryError",
    "PersonModel",
    "SeparationParams",
    "ToolPose",
    "clip_polygon_to_rect",
    "fit_homography",
    "max_robot_speed_mps",
    "points_in_polygon",
    "points_in_polygons",
    "polygon_fault",
    "protective_separation_m",
    "triangulate_polygon",
]


class GeometryError(ValueError):
    """A geometric input cannot be used (degenerate polygon, singular homography, ...)."""


# --------------------------------------------------------------------------------------------
# Poses and rotations


@dataclass(frozen=True)
class ToolPose:
    """Pose of the tracked tool (tracker body) in the cell frame.

    ``position_m`` is x, y, z in metres; ``quaternion_xyzw`` is the orientation (x, y, z, w),
    need not be normalised; ``time`` is seconds on the monotonic clock (or the replay clock).
    The fixed tool offset of the cell file is applied on top (``pose @ offset``).
    """

    position_m: tuple[float, float, float]
    quaternion_xyzw: tuple[float, float, float, float]
    time: float


def quaternion_to_matrix(q_xyzw: Sequence[float]) -> np.ndarray:
    """3x3 rotation matrix of a quaternion given as (x, y, z, w); normalises it first."""
    x, y, z, w = (float(v) for v in q_xyzw)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(n) or n < 1e-9:
        raise GeometryError(f"quaternion {tuple(q_xyzw)} has no rotation (norm {n:g})")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def rpy_to_matrix(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """Rotation from roll, pitch, yaw in degrees about fixed x, y, z: ``Rz @ Ry @ Rx``."""
    r, p, y = (math.radians(v) for v in (roll_deg, pitch_deg, yaw_deg))
    cr, sr = math.cos(r), math.sin(r)
    cp, sp = math.cos(p), math.sin(p)
    cy, sy = math.cos(y), math.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def rigid(rotation: np.ndarray, translation: Sequence[float]) -> np.ndarray:
    """4x4 homogeneous transform from a 3x3 rotation and a translation."""
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = np.asarray(translation, dtype=float)
    return t


def tool_transform(pose: ToolPose, offset: np.ndarray) -> np.ndarray:
    """Cell-from-tool transform: the tracker pose composed with the fixed mounting offset.

    ``offset`` is the tool frame expressed in the tracker frame (4x4), as the seeds' tracker
    calibration gives it (translation [13.55, 1.82, 49.17] mm, about 180 deg about z).
    """
    return rigid(quaternion_to_matrix(pose.quaternion_xyzw), pose.position_m) @ offset


# --------------------------------------------------------------------------------------------
# Polygons (image pixels or floor metres; both are plain 2-D here)


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
    edges = _PolygonEdges.build(polygons)
    return edges.contains(pts)


@dataclass(frozen=True)
class _PolygonEdges:
    """All edges of several polygons, stacked, so that a point test is one numpy pass."""

    x0: np.ndarray
    y0: np.ndarray
    dx_dy: np.ndarray  # (x1 - x0) / (y1 - y0), 0 where the edge is horizontal
    ylo: np.ndarray
    yhi: np.ndarray
    starts: np.ndarray  # index of the first edge of each polygon
    count: int

    @classmethod
    def build(cls, polygons: Sequence[np.ndarray]) -> _PolygonEdges:
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


# --------------------------------------------------------------------------------------------
# Homography (image pixels <-> floor metres)


def fit_homography(image_px: np.ndarray, floor_m: np.ndarray) -> np.ndarray:
    """Least-squares homography H with ``floor ~ H @ [u, v, 1]`` from >= 4 point pairs.

    Normalised DLT (Hartley): both point sets are centred and scaled before the SVD, which keeps
    the fit exact to ~1e-12 on exact pairs. Raises GeometryError for fewer than 4 pairs or a
    degenerate set (three of four points on a line, all points on a line, singular H).
    """
    src = np.asarray(image_px, dtype=float).reshape(-1, 2)
    dst = np.asarray(floor_m, dtype=float).reshape(-1, 2)
    if len(src) != len(dst):
        raise GeometryError(f"{len(src)} image points but {len(dst)} floor points")
    if len(src) < 4:
        raise GeometryError(f"a homography needs at least 4 point pairs, got {len(src)}")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise GeometryError("point pairs contain a non-finite number")
    ts, tn = _normaliser(src), _normaliser(dst)
    s = _apply(ts, src)
    d = _apply(tn, dst)
    rows = []
    for (x, y), (u, v) in zip(s, d, strict=True):
        rows.append([-x, -y, -1, 0, 0, 0, u * x, u * y, u])
        rows.append([0, 0, 0, -x, -y, -1, v * x, v * y, v])
    a = np.array(rows)
    _, sv, vt = np.linalg.svd(a)
    # a unique solution needs rank 8: the 8th singular value must stand clear of zero
    if sv[7] < 1e-8 * sv[0]:
        raise GeometryError("degenerate point pairs (three or more of them on one line)")
    hn = vt[-1].reshape(3, 3)
    hsv = np.linalg.svd(hn, compute_uv=False)
    if hsv[2] < 1e-8 * hsv[0]:
        raise GeometryError("degenerate homography (singular: maps the image onto a line)")
    h = np.linalg.inv(tn) @ hn @ ts
    return h / h[2, 2] if abs(h[2, 2]) > 1e-12 else h / np.linalg.norm(h)


def _normaliser(p: np.ndarray) -> np.ndarray:
    c = p.mean(axis=0)
    d = np.sqrt(((p - c) ** 2).sum(axis=1)).mean()
    if d < 1e-12:
        raise GeometryError("degenerate point pairs (all points coincide)")
    s = math.sqrt(2) / d
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]])


def _apply(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    q = np.c_[pts, np.ones(len(pts))] @ h.T
    return q[:, :2] / q[:, 2:3]


def apply_homography(h: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map (N, 2) points through H; also the homogeneous scale w (N,) (its sign tells the side
    of the horizon)."""
    p = np.asarray(pts, dtype=float).reshape(-1, 2)
    h = np.asarray(h, dtype=float)
    q = p @ h[:, :2].T + h[:, 2]  # same as [u, v, 1] @ H^T, without building the column
    w = q[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = q[:, :2] / w[:, None]
    return out, w


def reprojection_errors_px(h: np.ndarray, image_px: np.ndarray, floor_m: np.ndarray) -> np.ndarray:
    """Per-pair image distance (px) between each image point and its floor point mapped back
    through H^-1."""
    back, _ = apply_homography(np.linalg.inv(h), floor_m)
    return np.linalg.norm(back - np.asarray(image_px, dtype=float).reshape(-1, 2), axis=1)


# --------------------------------------------------------------------------------------------
# Camera model


@dataclass(frozen=True, eq=False)
class CameraModel:
    """A calibrated camera: pinhole (K, distortion, R, t) or a floor homography.

    ``homography`` maps undistorted pixels to floor metres (z = 0). With a pinhole calibration it
    is derived from K, R, t, so both kinds answer ``pixel_to_floor``; only the pinhole kind can
    project points above the floor.
    """

    width: int
    height: int
    camera_matrix: np.ndarray | None  # K, 3x3
    distortion: np.ndarray | None  # OpenCV coefficients (k1, k2, p1, p2[, k3, ...])
    rotation: np.ndarray | None  # R, cell -> camera
    translation_m: np.ndarray | None  # t, cell -> camera
    homography: np.ndarray  # undistorted px -> floor m
    w_sign: float  # sign of the homogeneous scale for pixels that see the floor

    @classmethod
    def pinhole(cls, width: int, height: int, k: np.ndarray, distortion: np.ndarray | None,
                rotation: np.ndarray, translation_m: np.ndarray) -> CameraModel:
        k = np.asarray(k, dtype=float)
        r = np.asarray(rotation, dtype=float)
        t = np.asarray(translation_m, dtype=float).reshape(3)
        # floor points (x, y, 0) project with K [r1 r2 t]; invert it for pixel -> floor
        m = k @ np.c_[r[:, 0], r[:, 1], t]
        if abs(np.linalg.det(m)) < 1e-12 * np.abs(m).max() ** 3:
            raise GeometryError("camera centre lies on the floor plane: no floor homography")
        h = np.linalg.inv(m)
        dist = None if distortion is None else np.asarray(distortion, dtype=float).reshape(-1)
        model = cls(width, height, k, dist, r, t, h / h[2, 2] if h[2, 2] else h, 1.0)
        # w = depth of the floor point / scale; pick the sign of a floor point in front
        centre = -r.T @ t
        ahead = centre + r.T @ np.array([0.0, 0.0, 1.0])
        target = np.array([ahead[0], ahead[1], 0.0])
        px, front = model.project(target[None])
        if front[0]:
            _, w = apply_homography(model.homography, px)
            sign = 1.0 if w[0] > 0 else -1.0
        else:  # camera looks up; floor visible only below the horizon, take the generic sign
            sign = 1.0
        return cls(width, height, k, dist, r, t, model.homography, sign)

    @classmethod
    def from_homography(cls, width: int, height: int, homography: np.ndarray,
                        image_px: np.ndarray, k: np.ndarray | None = None,
                        distortion: np.ndarray | None = None) -> CameraModel:
        """``homography`` maps undistorted pixels to the floor; ``image_px`` are the calibration
        points (raw pixels), used to fix which side of the horizon sees the floor."""
        dist = None if distortion is None else np.asarray(distortion, dtype=float).reshape(-1)
        kk = None if k is None else np.asarray(k, dtype=float)
        model = cls(width, height, kk, dist, None, None, np.asarray(homography, float), 1.0)
        _, w = apply_homography(model.homography, model.undistort_px(image_px))
        sign = 1.0 if np.median(w) > 0 else -1.0
        return cls(width, height, kk, dist, None, None, model.homography, sign)

    @property
    def can_project_3d(self) -> bool:
        return self.rotation is not None

    def undistort_px(self, px: np.ndarray) -> np.ndarray:
        """Raw pixels -> undistorted pixels (same K); unchanged without distortion."""
        p = np.asarray(px, dtype=float).reshape(-1, 2)
        if self.distortion is None or not np.any(self.distortion) or self.camera_matrix is None:
            return p
        out = cv2.undistortPoints(p.reshape(-1, 1, 2), self.camera_matrix, self.distortion,
                                  P=self.camera_matrix)
        return out.reshape(-1, 2).astype(float)

    def pixel_to_floor(self, px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw pixels (N, 2) -> floor points (N, 2) metres and a validity mask (N,).

        A pixel is invalid when its viewing ray never meets the floor in front of the camera
        (at or above the horizon).
        """
        xy, w = apply_homography(self.homography, self.undistort_px(px))
        valid = (w * self.w_sign > 0) & np.all(np.isfinite(xy), axis=1)
        return xy, valid

    def project(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell points (N, 3) -> raw pixels (N, 2) and a mask of points in front of the camera.

        Homography-only cameras can project only floor points: z is ignored (documented).
        """
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        if self.rotation is None:
            px, w = apply_homography(np.linalg.inv(self.homography), p[:, :2])
            front = (w * self.w_sign > 0) & np.all(np.isfinite(px), axis=1)
            return self._distort(px), front
        cam = p @ self.rotation.T + self.translation_m
        front = cam[:, 2] > 1e-6
        if len(p) == 0:
            return np.zeros((0, 2)), front
        dist = self.distortion if self.distortion is not None else np.zeros(5)
        rvec, _ = cv2.Rodrigues(self.rotation)
        px, _ = cv2.projectPoints(p.reshape(-1, 1, 3), rvec, self.translation_m, self.camera_matrix,
                                  dist)
        return px.reshape(-1, 2), front

    def _distort(self, undistorted_px: np.ndarray) -> np.ndarray:
        if self.distortion is None or not np.any(self.distortion) or self.camera_matrix is None:
            return undistorted_px
        k = self.camera_matrix
        norm = (undistorted_px - k[:2, 2]) / np.array([k[0, 0], k[1, 1]])
        pts = np.c_[norm, np.ones(len(norm))]
        px, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k,
                                  self.distortion)
        return px.reshape(-1, 2)


def look_at(eye_m: Sequence[float], target_m: Sequence[float],
            up: Sequence[float] = (0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Extrinsics (R, t) of a camera at ``eye_m`` looking at ``target_m`` (OpenCV convention:
    x right, y down, z forward); ``x_cam = R @ x_cell + t``."""
    eye = np.asarray(eye_m, dtype=float)
    fwd = np.asarray(target_m, dtype=float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(up, dtype=float))
    if np.linalg.norm(right) < 1e-9:
        raise GeometryError("look-at direction is parallel to up")
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    r = np.stack([right, down, fwd])
    return r, -r @ eye


# --------------------------------------------------------------------------------------------
# Person model and ISO/TS 15066 speed and separation monitoring


@dataclass(frozen=True)
class PersonModel:
    """A person as a vertical cylinder standing on the floor (metres).

    ``position_uncertainty_m`` is Z_d: the cylinder used for zone checks is widened by it.
    """

    radius_m: float = 0.3
    height_m: float = 1.9
    position_uncertainty_m: float = 0.1

    @property
    def zone_radius_m(self) -> float:
        return self.radius_m + self.position_uncertainty_m


@dataclass(frozen=True)
class SeparationParams:
    """ISO/TS 15066 speed and separation monitoring parameters (SI units).

    ``robot_speed_default_mps`` is the tool speed assumed when none is measured.
    """

    person_speed_mps: float = 1.6  # v_h (standard default when not measured)
    reaction_time_s: float = 0.1  # T_r: detection + logic + command latency
    deceleration_mps2: float = 2.0  # a: robot braking deceleration (T_s = v_r / a)
    intrusion_distance_m: float = 0.2  # C
    robot_uncertainty_m: float = 0.02  # Z_r
    robot_speed_default_mps: float = 1.0


def protective_separation_m(robot_speed_mps: float, params: SeparationParams,
                            position_uncertainty_m: float) -> float:
    """S_p = S_h + S_r + S_s + C + Z_d + Z_r (ISO/TS 15066), metres.

    S_h = v_h (T_r + T_s), S_r = v_r T_r, S_s = v_r^2 / (2 a), T_s = v_r / a.
    """
    v_r = abs(float(robot_speed_mps))
    p = params
    t_s = v_r / p.deceleration_mps2
    s_h = p.person_speed_mps * (p.reaction_time_s + t_s)
    s_r = v_r * p.reaction_time_s
    s_s = v_r * v_r / (2.0 * p.deceleration_mps2)
    return s_h + s_r + s_s + p.intrusion_distance_m + position_uncertainty_m + p.robot_uncertainty_m


def max_robot_speed_mps(separation_m: float, params: SeparationParams,
                        position_uncertainty_m: float) -> float:
    """Largest robot speed whose S_p fits in ``separation_m`` (inverse of
    ``protective_separation_m``): sqrt(b^2 + 2 a (d - C - Z_d - Z_r - v_h T_r)) - b with
    b = a T_r + v_h; 0 when that is negative."""
    p = params
    a = p.deceleration_mps2
    b = a * p.reaction_time_s + p.person_speed_mps
    room = (separation_m - p.intrusion_distance_m - position_uncertainty_m
            - p.robot_uncertainty_m - p.person_speed_mps * p.reaction_time_s)
    if room <= 0:
        return 0.0
    return max(0.0, math.sqrt(b * b + 2 * a * room) - b)


# --------------------------------------------------------------------------------------------
# FCL helpers


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
    p = np.asarray(points_m, dtype=float)
    if polygon_signed_area(p) < 0:
        p = p[::-1]
    pieces = [p] if is_convex(p) else [p[t] for t in triangulate_polygon(p)]
    return [fcl.CollisionObject(_convex_prism(q, z_min_m, z_max_m), fcl.Transform())
            for q in pieces]


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
