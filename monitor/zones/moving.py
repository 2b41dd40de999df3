"""Zones that follow the tool: where a tool-frame zone is at a pose, how much it grows with the
tool's speed, and what it is when the pose is not fresh (docs/moving-zones.md).

A protective or warning volume with ``follow:`` is given in the tool frame (or the flange
frame, which the tool calibration's ``given_as: tracker_in_tool`` offset places). At each step
with a fresh pose it is moved by the same chain the tool separation uses (cell <- tracker_frame
<- tracker pose <- tool offset); ``grow_with_speed`` inflates it by S_p at the measured tool
speed (at most ``max_growth_m``). Without a pose, with one older than ``policy.pose_timeout``
or one that places nothing (not finite, zero quaternion) the zone is its ``max_volume``, a
cell-frame volume that must hold every place the zone can reach: the monitor cannot know where
the tool went, so it assumes it is anywhere it can be.

Pure functions only: the FCL placement and the per-person test are in ``moving_check``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from monitor import geometry as geo
from monitor.zones.schema import BoxZone, CellSpec, CylinderZone, ExtrudeZone


@dataclass(frozen=True)
class ToolState:
    """The tool as the moving zones see it at one step: the newest accepted pose (tracker
    frame, as received), its age (``now`` minus its receive time; None: no pose), the age above
    which it is stale (``policy.pose_timeout``) and the measured tool speed (None: unknown)."""

    pose: geo.ToolPose | None = None
    age_s: float | None = None
    timeout_s: float = 0.1
    speed_mps: float | None = None

    @property
    def fresh(self) -> bool:
        """A pose at most ``timeout_s`` old (a NaN age, or a pose from the future beyond the
        timeout, is not fresh)."""
        return self.pose is not None and self.age_s is not None \
            and abs(float(self.age_s)) <= self.timeout_s

    @classmethod
    def at(cls, now: float, pose: geo.ToolPose | None, pose_time: float | None,
           timeout_s: float, speed_mps: float | None) -> ToolState:
        """The state at ``now`` of a pose received at ``pose_time``."""
        age = None if pose is None or pose_time is None else now - pose_time
        return cls(pose, age, timeout_s, speed_mps)


def follows_tool(z: Any) -> bool:
    """The zone is a volume that follows the tool."""
    return getattr(z, "follow", None) is not None


def cell_from_zone(spec: CellSpec, pose: geo.ToolPose) -> np.ndarray | None:
    """4x4 transform of a following zone's frame in the cell at a tracker pose: the tracker
    frame, the pose, the tool offset (``flange`` zones need the calibration's
    ``tracker_in_tool`` offset, so both frames are that one). None when the pose places
    nothing (not finite, zero quaternion, no tool section)."""
    if spec.tool is None:
        return None
    if not all(math.isfinite(float(v)) for v in (*pose.position_m, *pose.quaternion_xyzw)):
        return None
    try:
        if spec.tracker_frame is not None:
            pose = geo.pose_in_frame(spec.tracker_frame.cell_from_tracker(), pose)
        m = geo.tool_transform(pose, spec.tool.offset.tool_in_tracker())
    except geo.GeometryError:  # a zero quaternion
        return None
    return m if np.all(np.isfinite(m)) else None


def transform_points(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) points of a zone's frame in the cell."""
    return np.asarray(points, dtype=float) @ m[:3, :3].T + m[:3, 3]


def growth_m(z: Any, params: geo.SeparationParams, speed_mps: float | None) -> float:
    """How far the zone is inflated at this tool speed: S_p (ISO/TS 15066) at the speed, at
    most ``max_growth_m``; 0 without ``grow_with_speed``. Z_d is left out of S_p because the
    person cylinder of the zone check is already widened by it. An unknown speed is the zone
    file's ``robot_speed_default_mps``; a speed that is not finite grows to the maximum."""
    f = z.follow
    if not f.grow_with_speed:
        return 0.0
    v = params.robot_speed_default_mps if speed_mps is None else abs(float(speed_mps))
    s_p = geo.protective_separation_m(v, params, position_uncertainty_m=0.0)
    return float(min(s_p, f.max_growth_m)) if not math.isnan(s_p) else float(f.max_growth_m)


def max_zone(z: Any) -> BoxZone | CylinderZone | ExtrudeZone:
    """The zone at its maximum size: its ``max_volume`` as a cell-frame zone of the same id,
    kind and speed scale (what coverage, drawing and a stale pose use)."""
    mv = z.follow.max_volume
    cls = {"box": BoxZone, "cylinder": CylinderZone, "extrude": ExtrudeZone}[mv.shape]
    return cls(id=z.id, name=z.name, kind=z.kind, enabled=z.enabled, speed_scale=z.speed_scale,
               unobserved_ok=z.unobserved_ok, **{k: getattr(mv, k) for k in type(mv).model_fields})


def follow_faults(spec: CellSpec) -> list[str]:
    """One line per fault of the file's following zones (empty when they are usable)."""
    out = []
    tool = spec.tool
    for z in spec.zones:
        if not follows_tool(z):
            continue
        f = z.follow
        where = f"zone '{z.id}': follow"
        if z.kind not in ("protective", "warning"):
            out.append(f"{where}: only protective and warning zones may follow the tool, "
                       f"not {z.kind}")
        if tool is None:
            out.append(f"{where}: needs the zone file's 'tool:' section (its offset places the "
                       "tool frame on the tracker)")
        elif f.frame == "flange" and tool.offset.given_as != "tracker_in_tool":
            out.append(f"{where}: frame 'flange' needs tool.offset given_as: tracker_in_tool "
                       "(the tracker's mounting on the flange, as 'zones calibrate-tool' "
                       "writes it); use frame: tool for a tool_in_tracker offset")
        if f.grow_with_speed and f.max_growth_m is None:
            out.append(f"{where}: grow_with_speed needs max_growth_m (the largest growth, m)")
        if not f.grow_with_speed and f.max_growth_m is not None:
            out.append(f"{where}: max_growth_m is only for grow_with_speed: true")
    return out
