"""Is a camera's lens distortion model usable over its whole image?

OpenCV's distortion model is a polynomial (or rational) function of the undistorted radius r:
``r_d(r) = r * (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)``, plus tangential
(p1, p2), thin-prism (s1..s4) and tilt (tauX, tauY) terms. Fitted coefficients are only valid
over the radii the calibration saw; beyond them the polynomial can turn back (r_d falls again),
and then one pixel has two viewing rays: undistortion picks one of them, projection maps floor
points from both to the same pixel, and a person can be placed tens of metres from where they
stand. This module refuses such a model before it is used.

Two checks, in normalised camera coordinates (pixels through K^-1):

* radial: r_d(r) must rise from the centre to beyond the image's farthest corner, and keep at
  least ``MIN_SLOPE`` of its slope at the centre on the way (a lens that flattens to nearly zero
  slope is at its fold: a pixel there maps to a wide range of rays and the second branch is
  within reach of a pixel's error);
* the whole map (tangential, prism and tilt terms included): on every ray that lands in the
  image, its Jacobian must keep a positive determinant and a smallest singular value of at least
  ``MIN_SLOPE`` of the centre's (no direction folds or collapses).

What it cannot do: tell a correct model from a wrong one that is still monotonic (that is the
reprojection error's job), or judge rays outside the image.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

# the least slope dr_d/dr (relative to the centre's) allowed over the image: under it the model
# is at or near its fold (1/4: a pixel there spans four times the ray angle of a centre pixel)
MIN_SLOPE = 0.25
# how far out a ray is looked for (normalised radius 20: 87 deg off axis)
_R_LIMIT = 20.0
_RADIAL_SAMPLES = 200_001
_GRID = 161


def _coefficients(distortion: np.ndarray) -> np.ndarray:
    """The 14 OpenCV coefficients (k1, k2, p1, p2, k3, k4, k5, k6, s1..s4, tauX, tauY)."""
    out = np.zeros(14)
    d = np.asarray(distortion, dtype=float).reshape(-1)
    out[: len(d)] = d
    return out


def radial_distorted(r: np.ndarray, distortion: np.ndarray) -> np.ndarray:
    """r_d(r) of the radial terms alone (normalised units)."""
    c = _coefficients(distortion)
    r2 = np.asarray(r, dtype=float) ** 2
    num = 1 + r2 * (c[0] + r2 * (c[1] + r2 * c[4]))
    den = 1 + r2 * (c[5] + r2 * (c[6] + r2 * c[7]))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(r) * num / den


def _corner_radius(k: np.ndarray, width: int, height: int) -> tuple[float, np.ndarray]:
    """Largest normalised (distorted) radius of the image corners, and the corners."""
    corners = np.array([[0, 0], [width, 0], [0, height], [width, height]], dtype=float)
    norm = (np.linalg.inv(k) @ np.c_[corners, np.ones(4)].T).T[:, :2]
    return float(np.linalg.norm(norm, axis=1).max()), corners


def distortion_fault(k: np.ndarray, distortion: np.ndarray | None, width: int,
                     height: int) -> str | None:
    """None when the distortion model is one-to-one over the image; else one line saying where
    it folds. ``k`` is the 3x3 camera matrix (already checked), ``distortion`` the OpenCV
    coefficients (4, 5, 8, 12 or 14 of them)."""
    if distortion is None or len(distortion) == 0 or not np.any(distortion):
        return None
    k = np.asarray(k, dtype=float)
    d = np.asarray(distortion, dtype=float).reshape(-1)
    if not np.all(np.isfinite(d)):
        return "distortion contains a non-finite number"
    need, _ = _corner_radius(k, width, height)
    f = math.sqrt(abs(k[0, 0] * k[1, 1]))  # px per normalised unit, to report in pixels
    fault = _radial_fault(d, need, f)
    if fault is not None:
        return fault
    return _map_fault(k, d, width, height, need)


def _radial_fault(d: np.ndarray, need: float, f: float) -> str | None:
    r = np.linspace(0.0, _R_LIMIT, _RADIAL_SAMPLES)
    g = radial_distorted(r, d)
    slope = np.gradient(g, r)
    bad = ~np.isfinite(g) | (slope < MIN_SLOPE * slope[0])
    reached = g >= need
    first_reach = int(np.argmax(reached)) if reached.any() else len(r)
    first_bad = int(np.argmax(bad)) if bad.any() else len(r)
    if first_bad > first_reach:
        return None
    falls = ~np.isfinite(g) | (slope <= 0)
    end = int(np.argmax(falls)) if falls.any() else len(r) - 1
    peak = float(np.nanmax(g[: end + 1]))
    what = ("folds back" if peak < need else "nearly folds back") if falls.any() else "flattens"
    return (f"distortion {what} inside the image: r_d(r) stops rising at {f * g[first_bad]:.0f} "
            f"px from the centre (slope {slope[first_bad] / slope[0]:.2f} of the centre's, "
            f"peak {f * peak:.0f} px) but the image corners are {f * need:.0f} px away: one "
            "pixel would map to two floor points (check the distortion coefficients; they "
            "hold only over the radii the calibration saw)")


def _map_fault(k: np.ndarray, d: np.ndarray, width: int, height: int,
               need: float) -> str | None:
    """The full map on a grid of undistorted rays reaching a little beyond the image: every ray
    that lands in the image must keep a non-degenerate, orientation-keeping Jacobian."""
    # the radial terms alone reach the corners at r*; the other terms move a corner's ray a
    # little, so the grid reaches 10 % further (rays landing outside the image are not judged)
    r = np.linspace(0.0, _R_LIMIT, _RADIAL_SAMPLES)
    reach = float(r[int(np.argmax(radial_distorted(r, d) >= need))]) * 1.1
    axis = np.linspace(-reach, reach, _GRID)
    step = axis[1] - axis[0]
    x, y = np.meshgrid(axis, axis)
    pts = np.c_[x.ravel(), y.ravel(), np.ones(x.size)]
    proj, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, d)
    px = proj.reshape(_GRID, _GRID, 2)
    if not np.all(np.isfinite(px)):
        return "distortion maps rays inside the image to non-finite pixels"
    du_dy, du_dx = np.gradient(px[..., 0], step)
    dv_dy, dv_dx = np.gradient(px[..., 1], step)
    jac = np.stack([np.stack([du_dx, du_dy], -1), np.stack([dv_dx, dv_dy], -1)], -2)
    jac = jac / math.sqrt(abs(k[0, 0] * k[1, 1]))
    det = np.linalg.det(jac)
    smallest = np.linalg.svd(jac, compute_uv=False)[..., -1]
    centre = smallest[_GRID // 2, _GRID // 2]
    inside = ((np.hypot(x, y) <= reach) & (px[..., 0] >= 0) & (px[..., 0] <= width)
              & (px[..., 1] >= 0) & (px[..., 1] <= height))
    bad = inside & ((det <= 0) | (smallest < MIN_SLOPE * centre))
    if not bad.any():
        return None
    i, j = np.argwhere(bad)[0]
    u, v = px[i, j]
    return (f"distortion folds the image near pixel ({u:.0f}, {v:.0f}) (tangential, prism or "
            "tilt terms): one pixel would map to two floor points (check the distortion "
            "coefficients)")
