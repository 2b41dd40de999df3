"""Speed and separation monitoring in the zone check: S_p, the measured separation and the
command's speed scale for one frame, and the start-up checks that separation monitoring needs.

Kept apart from ``check`` so that the per-frame query stays one small call; formulas are in
``monitor.geometry.separation`` and docs/separation.md.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from monitor import geometry as geo
from monitor.errors import ConfigError
from monitor.zones.files import Cell
from monitor.zones.prepare import PreparedCell
from monitor.zones.volumes import FCL_DISTANCE_MARGIN_M


# FCL's person-cylinder to tool distance was measured against closed forms to over-report by
# up to 0.31 mm (never under): the separation is reduced by this much before it is used.
@dataclasses.dataclass(frozen=True)
class SeparationAnswer:
    """``required_m`` S_p at the tool speed used; ``separation_m`` the smallest person-to-tool
    distance (None: no person to measure); ``speed_scale`` the fraction of the programmed speed
    v_max(separation) allows (None: not evaluated, no person)."""

    required_m: float | None
    separation_m: float | None
    speed_scale: float | None


def evaluate_separation(prep: PreparedCell, tool_pose: geo.ToolPose | None,
                        tool_speed_mps: float | None,
                        measure: Callable[[], float | None]) -> SeparationAnswer:
    """The separation part of one frame's ``ZoneReport``.

    ``measure()`` gives the raw FCL distance (None when no person can be measured); it is not
    called without a tool. Fail-safe rules: a tool pose with no tool in the zone file, a
    non-finite pose, speed or distance all give separation 0 and speed scale 0 (STOP), never
    NaN. An unknown speed (None) is the zone file's ``robot_speed_default_mps``.
    """
    if tool_pose is None:
        return SeparationAnswer(None, None, None)
    params = dataclasses.replace(prep.separation,
                                 position_uncertainty_m=prep.person.position_uncertainty_m)
    speed = params.robot_speed_default_mps if tool_speed_mps is None else float(tool_speed_mps)
    speed = abs(speed) if math.isfinite(speed) else math.inf
    required = geo.protective_separation_m(speed, params)
    pose_ok = all(math.isfinite(float(v)) for v in (*tool_pose.position_m,
                                                    *tool_pose.quaternion_xyzw))
    if prep.tool is None or not pose_ok or not math.isfinite(speed):
        return SeparationAnswer(required, 0.0, 0.0)
    raw = measure()
    if raw is None:
        return SeparationAnswer(required, None, None)
    raw = float(raw)
    separation = max(raw - FCL_DISTANCE_MARGIN_M, 0.0) if math.isfinite(raw) else 0.0
    programmed = prep.cell.spec.separation.programmed_speed_mps
    scale = geo.separation_speed_scale(separation, params, programmed, tool_speed_mps=speed)
    return SeparationAnswer(required, separation, scale)


def pose_in_cell(prep: PreparedCell, pose: geo.ToolPose | None) -> geo.ToolPose | None:
    """A tracker pose (tracker's reference frame) in the cell frame, through the zone file's
    ``tracker_frame``; unchanged without one. A pose that is not finite stays as it is (the
    separation then fails safe)."""
    frame = prep.cell.spec.tracker_frame
    if pose is None or frame is None:
        return pose
    if not all(math.isfinite(float(v)) for v in (*pose.position_m, *pose.quaternion_xyzw)):
        return pose
    try:
        return geo.pose_in_frame(frame.cell_from_tracker(), pose)
    except geo.GeometryError:  # a zero quaternion: leave it for the fail-safe path
        return pose


def tool_points_in_tracker(prep: PreparedCell) -> np.ndarray:
    """(8, 3) points in the tracker frame whose motion bounds the whole tool's: the corners of
    the cube around the tool's bounding sphere. The speed of a rigid body's point is convex in
    the point, so no point of the tool moves faster than the fastest of these corners (the
    estimate errs high, never low). Empty (0, 3) without a tool."""
    if prep.tool is None:
        return np.zeros((0, 3))
    t = prep.tool
    r = t.bound_radius
    corners = np.array([[x, y, z] for x in (-r, r) for y in (-r, r) for z in (-r, r)])
    pts = t.bound_centre + corners
    m = t.offset @ t.local
    return pts @ m[:3, :3].T + m[:3, 3]


def separation_faults(cell: Cell) -> list[str]:
    """Why this zone file cannot be used with separation monitoring on (empty when it can)."""
    out = []
    if cell.spec.tool is None:
        out.append("separation monitoring needs a 'tool:' section (the tool's shape and "
                   "offset): without it S_p would never be evaluated")
    if not cell.camera_models:
        out.append("separation monitoring needs at least one calibrated camera (persons "
                   "must be placed in the cell to measure their distance to the tool)")
    return out


def require_separation_ready(cell: Cell) -> None:
    """Raise ConfigError (one line) when separation monitoring cannot work with this cell."""
    faults = separation_faults(cell)
    if faults:
        raise ConfigError(f"{cell.label}: {faults[0]}")


def with_reaction_time(prep: PreparedCell, budget: geo.ReactionBudget) -> PreparedCell:
    """The prepared cell with T_r = the larger of the zone file's value and the configuration's
    worst-case delays (``budget``): ``monitor run`` uses this so that T_r is never smaller than
    what the configuration allows to pass."""
    t_r = max(prep.separation.reaction_time_s, budget.total_s())
    return dataclasses.replace(prep, separation=dataclasses.replace(prep.separation,
                                                                    reaction_time_s=t_r))
