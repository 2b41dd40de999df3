"""Rotations, rigid transforms and the tracked tool pose (cell frame, metres)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monitor.geometry.errors import GeometryError


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


def matrix_to_quaternion_xyzw(r: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w), w >= 0, of a rotation matrix (Shepperd's method)."""
    m = np.asarray(r, dtype=float)
    tr = float(np.trace(m))
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s)
    n = math.sqrt(sum(v * v for v in q))
    sign = -1.0 if q[3] < 0 else 1.0
    return tuple(float(sign * v / n) for v in q)  # type: ignore[return-value]


def pose_in_frame(frame: np.ndarray, pose: ToolPose) -> ToolPose:
    """``pose`` (given in some reference frame) expressed in the frame that ``frame`` (4x4,
    outer_T_reference) maps into: outer_T_reference @ reference_T_body."""
    m = frame @ rigid(quaternion_to_matrix(pose.quaternion_xyzw), pose.position_m)
    return ToolPose(tuple(float(v) for v in m[:3, 3]), matrix_to_quaternion_xyzw(m[:3, :3]),
                    pose.time)


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

    ``offset`` is the tool frame expressed in the tracker frame (4x4, tool_in_tracker). The
    tracker report's calibration gives the other direction: the tracker's mounting on the
    robot flange
    (tracker in flange frame: translation [13.55, 1.82, 49.17] mm, about 180 deg about z; its
    quaternion is printed w-first, [0.004 0.005 -0.002 -1] = w, x, y, z). With the tool frame
    at the flange, ``offset`` is the inverse of that (the zone file's ``given_as:
    tracker_in_tool``). ``pose`` must already be in the cell frame (``tracker_frame``).
    """
    return rigid(quaternion_to_matrix(pose.quaternion_xyzw), pose.position_m) @ offset

