"""Floor homographies and camera models (image pixels <-> cell metres)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from monitor.geometry.errors import GeometryError


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
        # (x, y, 1) = depth * inv(m) @ (u, v, 1) with depth = camera z of the floor point:
        # keeping inv(m) unnormalised (only a positive scale) makes w = 1 / depth, so w > 0
        # exactly for floor points in front of the camera, at any pitch (the horizon is w = 0)
        h = np.linalg.inv(m)
        scale = abs(h[2, 2]) if abs(h[2, 2]) > 1e-12 * np.abs(h).max() else np.abs(h).max()
        dist = None if distortion is None else np.asarray(distortion, dtype=float).reshape(-1)
        return cls(width, height, k, dist, r, t, h / scale, 1.0)

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
        if np.any(w > 0) and np.any(w < 0):
            raise GeometryError("the horizon of this homography runs between the calibration "
                                "points: some pixels would map behind the camera (check the "
                                "point pairs)")
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

    def horizon_row_px(self, column_px: float | None = None) -> float | None:
        """Image row (undistorted pixels) of the horizon at ``column_px`` (the image centre by
        default): pixels on the floor side of it meet the floor in front of the camera, the
        others never do. None when the horizon is vertical in the image (a camera rolled 90
        degrees) or at infinity (a camera looking straight down). The line is where the third
        row of the floor homography gives w = 0; which side sees the floor is ``w_sign``."""
        u = self.width / 2 if column_px is None else float(column_px)
        h31, h32, h33 = (float(x) for x in self.homography[2])
        if abs(h32) < 1e-15 * max(abs(h31), abs(h33), 1e-300):
            return None
        return -(h31 * u + h33) / h32

    def floor_is_below_horizon(self) -> bool:
        """True when the floor lies below the horizon row (image y grows downwards), the usual
        upright camera; False for an upside-down camera."""
        return bool(self.homography[2, 1] * self.w_sign > 0)

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

