"""Closed-loop calibration of the tracked tool: the tracker's mounting on the robot flange and
the tracker's reference frame in the cell, from pairs of robot flange poses and tracker poses.

The OTUS tracker measures its body's pose relative to the pose where it was last reset (its
reference frame), not in the cell. With the tracker on the robot flange, for every robot pose
i::

    cell_T_flange[i] @ flange_T_tracker = cell_T_reference @ reference_T_tracker[i]
    (A_i X = Y B_i)

Relative motions between two poses remove Y: ``A_ij X = X B_ij`` with ``A_ij = A_i^-1 A_j`` and
``B_ij = B_i^-1 B_j`` (the Sylvester-type AX = XB of hand-eye calibration, as the seed report
solves it). The rotation of X is the least-squares fit of the rotation axes (Park and Martin
1994: R_X = (M^T M)^(-1/2) M^T with M = sum beta alpha^T, alpha and beta the rotation vectors of
A_ij and B_ij); its translation solves (R_Aij - I) t_X = R_X t_Bij - t_Aij in least squares.
Y then follows from every pose (rotations averaged by SVD, translations by the mean).

All transforms are 4x4 homogeneous matrices, metres. Pure functions.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from monitor.geometry.errors import GeometryError


def rotation_vector(r: np.ndarray) -> np.ndarray:
    """Axis * angle (rad) of a rotation matrix (robust near 0 and pi)."""
    import cv2

    vec, _ = cv2.Rodrigues(np.asarray(r, dtype=float))
    return vec.reshape(3)


def rotation_angle_deg(r: np.ndarray) -> float:
    c = (np.trace(np.asarray(r, dtype=float)) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _nearest_rotation(m: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def invert_rigid(t: np.ndarray) -> np.ndarray:
    """The inverse of a 4x4 rigid transform (rotation transposed, no general inversion)."""
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out


@dataclass(frozen=True)
class ToolCalibration:
    """Result of ``calibrate_tool``.

    ``flange_T_tracker`` (X): the tracker body in the flange frame (its mounting);
    ``cell_T_reference`` (Y): the tracker's reference frame in the cell (the zone file's
    ``tracker_frame``); ``residual_mm`` and ``residual_deg`` per pose: how far
    ``Y @ B_i`` lies from ``A_i @ X`` (the closed loop's disagreement).
    """

    flange_T_tracker: np.ndarray
    cell_T_reference: np.ndarray
    residual_mm: np.ndarray
    residual_deg: np.ndarray
    rotation_spread_deg: float  # largest relative rotation among the pose pairs


MIN_POSES = 3
MIN_ROTATION_DEG = 5.0  # pairs turning less than this carry no information about the axes


def calibrate_tool(flange_poses: list[np.ndarray] | np.ndarray,
                   tracker_poses: list[np.ndarray] | np.ndarray) -> ToolCalibration:
    """Solve A_i X = Y B_i for X (tracker on flange) and Y (tracker reference in the cell).

    ``flange_poses``: cell_T_flange from the robot controller; ``tracker_poses``:
    reference_T_tracker from the tracker, same order. Needs at least 3 poses whose relative
    rotations turn about at least two different axes; raises GeometryError otherwise.
    """
    a = np.asarray(flange_poses, dtype=float).reshape(-1, 4, 4)
    b = np.asarray(tracker_poses, dtype=float).reshape(-1, 4, 4)
    if len(a) != len(b):
        raise GeometryError(f"{len(a)} flange poses but {len(b)} tracker poses")
    if len(a) < MIN_POSES:
        raise GeometryError(f"tool calibration needs at least {MIN_POSES} pose pairs, got {len(a)}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise GeometryError("pose pairs contain a non-finite number")
    alphas, betas, rows, rhs = [], [], [], []
    spread = 0.0
    n = len(a)
    # every pair for a few poses; for many, each pose with its next 10 (the closed form is
    # only the start of the joint fit, and all n^2 / 2 pairs would cost seconds)
    pairs = (itertools.combinations(range(n), 2) if n <= 30
             else ((i, (i + k) % n) for i in range(n) for k in range(1, 11)))
    for i, j in pairs:
        aij = invert_rigid(a[i]) @ a[j]
        bij = invert_rigid(b[i]) @ b[j]
        al, be = rotation_vector(aij[:3, :3]), rotation_vector(bij[:3, :3])
        spread = max(spread, float(np.degrees(np.linalg.norm(al))))
        if np.degrees(np.linalg.norm(al)) < MIN_ROTATION_DEG:
            continue
        alphas.append(al)
        betas.append(be)
        rows.append(aij)
        rhs.append(bij)
    if len(alphas) < 2:
        raise GeometryError(f"the poses hardly turn (largest relative rotation {spread:.1f} deg): "
                            "turn the flange by 20 deg or more about different axes")
    al = np.array(alphas)
    be = np.array(betas)
    # a unique rotation needs relative rotation axes that span at least a plane
    axes = al / np.linalg.norm(al, axis=1, keepdims=True)
    if np.linalg.svd(axes, compute_uv=False)[1] < 0.1:
        raise GeometryError("every pose turns about the same axis: the rotation about it "
                            "cannot be found (turn the flange about a second axis)")
    # alpha = R_X beta for every pair: R_X = argmin sum |R beta - alpha|^2, the orthogonal
    # Procrustes solution (nearest rotation to sum alpha beta^T), as Park and Martin
    rx = _nearest_rotation(al.T @ be)
    lhs = np.vstack([aij[:3, :3] - np.eye(3) for aij in rows])
    vec = np.concatenate([rx @ bij[:3, 3] - aij[:3, 3] for aij, bij in zip(rows, rhs,
                                                                            strict=True)])
    tx, *_ = np.linalg.lstsq(lhs, vec, rcond=None)
    x = np.eye(4)
    x[:3, :3] = rx
    x[:3, 3] = tx
    ys = np.array([a[i] @ x @ invert_rigid(b[i]) for i in range(len(a))])
    y = np.eye(4)
    y[:3, :3] = _nearest_rotation(ys[:, :3, :3].sum(axis=0))
    y[:3, 3] = ys[:, :3, 3].mean(axis=0)
    x, y = _refine(a, b, x, y)
    res_mm = np.empty(len(a))
    res_deg = np.empty(len(a))
    for i in range(len(a)):
        lhs_i = a[i] @ x
        rhs_i = y @ b[i]
        res_mm[i] = 1000.0 * float(np.linalg.norm(lhs_i[:3, 3] - rhs_i[:3, 3]))
        res_deg[i] = rotation_angle_deg(lhs_i[:3, :3].T @ rhs_i[:3, :3])
    return ToolCalibration(x, y, res_mm, res_deg, spread)


def _refine(a: np.ndarray, b: np.ndarray, x: np.ndarray, y: np.ndarray, rounds: int = 50
            ) -> tuple[np.ndarray, np.ndarray]:
    """Both transforms at once over every pose (A_i X = Y B_i), started from the closed form:
    the closed form uses relative motions, whose noise is twice each pose's; this fit uses each
    pose once. Rotations by alternating chordal least squares (each step the nearest rotation
    to a sum, so it cannot diverge), then both translations in one linear least squares."""
    ra, rb = a[:, :3, :3], b[:, :3, :3]
    rx, ry = x[:3, :3], y[:3, :3]
    for _ in range(rounds):
        ry_new = _nearest_rotation(np.einsum("nij,jk,nlk->il", ra, rx, rb))  # sum Ra Rx Rb^T
        rx_new = _nearest_rotation(np.einsum("nji,jk,nkl->il", ra, ry_new, rb))  # Ra^T Ry Rb
        done = (np.abs(rx_new - rx).max() < 1e-12 and np.abs(ry_new - ry).max() < 1e-12)
        rx, ry = rx_new, ry_new
        if done:
            break
    # Ra t_X - t_Y = Ry t_B - t_A for every pose
    lhs = np.concatenate([np.hstack([ra[i], -np.eye(3)]) for i in range(len(a))])
    rhs = np.concatenate([ry @ b[i, :3, 3] - a[i, :3, 3] for i in range(len(a))])
    t, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    xx, yy = np.eye(4), np.eye(4)
    xx[:3, :3], xx[:3, 3] = rx, t[:3]
    yy[:3, :3], yy[:3, 3] = ry, t[3:]
    return xx, yy


def matrix_to_rpy_deg(r: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (deg, about fixed x, y, z; ``R = Rz Ry Rx``) of a rotation matrix,
    the inverse of ``rpy_to_matrix``."""
    r = np.asarray(r, dtype=float)
    pitch = float(np.arcsin(np.clip(-r[2, 0], -1.0, 1.0)))
    if abs(r[2, 0]) < 1 - 1e-9:
        roll = float(np.arctan2(r[2, 1], r[2, 2]))
        yaw = float(np.arctan2(r[1, 0], r[0, 0]))
    else:  # gimbal lock: yaw absorbs the roll
        roll = 0.0
        yaw = float(np.arctan2(-r[0, 1], r[1, 1]))
    return tuple(float(np.degrees(v)) for v in (roll, pitch, yaw))  # type: ignore[return-value]
