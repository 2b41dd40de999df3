"""Placement keeps every position the evidence allows: a short person with the feet in view
(crouching, kneeling, lying) keeps the feet's position, and a person on a raised floor region
(platform, mezzanine, pit) declared in the zone file is placed on it (docs/occlusion.md).

The camera is the demo camera (cam0, 1280x720 at (0, -6, 3.2) m looking at (0, 0, 0.8) m)."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from monitor import geometry as geo
from monitor import occlusion as occ
from monitor import zones as zn
from monitor.scene import DEMO_CAMERA

DEMO = Path(__file__).resolve().parents[1] / "zones" / "demo-cell.yaml"


def demo_data() -> dict:
    return copy.deepcopy(zn.read_cell_data(DEMO))


def person_box(x: float, y: float, head_m: float, floor_z_m: float = 0.0,
               width_m: float | None = None) -> np.ndarray:
    """The box a perfect detector gives for a person whose feet are at (x, y, floor_z_m) and
    whose head top is ``head_m`` above them (``width_m``: the figure's width, e.g. lying)."""
    feet, head = DEMO_CAMERA.project(np.array([[x, y, floor_z_m], [x, y, floor_z_m + head_m]]))
    if width_m is None:
        half = 0.2 * (feet[1] - head[1])
    else:
        a, b = DEMO_CAMERA.project(np.array([[x - width_m / 2, y, floor_z_m],
                                             [x + width_m / 2, y, floor_z_m]]))
        half = (b[0] - a[0]) / 2
    return np.array([[feet[0] - half, head[1], feet[0] + half, feet[1]]])


def tool_pose_at(cell: zn.Cell, axis_xy: np.ndarray, z: float = 0.2) -> geo.ToolPose:
    """A tracker pose that puts the demo tool's axis (a vertical cylinder, radius 0.05 m,
    from z up 0.3 m) at ``axis_xy``: the pose is the tracker's, a few mm off the axis."""
    prep = cell.prepared
    unit = geo.ToolPose((0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0), 0.0)
    shift = geo.tool_transform(unit, prep.tool.offset)[:2, 3]
    return geo.ToolPose((float(axis_xy[0] - shift[0]), float(axis_xy[1] - shift[1]), z),
                        (0.0, 0.0, 0.0, 1.0), 0.0)


def true_separation(cell: zn.Cell, x: float, y: float, pose: geo.ToolPose,
                    floor_z_m: float = 0.0) -> float:
    """The check's own answer for a standing person in clear view at (x, y): a point
    placement, so the separation is the exact one of the nominal cylinder there."""
    box = person_box(x, y, 1.75, floor_z_m)
    model = cell.camera_models["cam0"]
    assert not occ.place_persons(box, model, 1280, 720).hidden[0]
    return zn.check_persons(cell, "cam0", box, tool_pose=pose,
                            tool_speed_mps=0.1).tool_separation_m


# ------------------------------------------------------------------ short, feet in view


@pytest.mark.parametrize("head_m", [0.3, 0.6, 0.85])
@pytest.mark.parametrize("spot", [(0.0, -2.0), (1.5, -1.5), (0.0, 0.5), (-1.0, 1.5)])
@pytest.mark.parametrize("side", [(1.0, 0.0), (0.0, 1.0), (0.0, -1.0)])
def test_a_crouching_persons_separation_never_exceeds_the_true_one(head_m, spot, side):
    """A crouching person (head 0.6 m; 0.3 m lying, 0.85 m kneeling low) with the tool 0.1 m
    away: the box is short, so the feet may be hidden and the head is placed over the height
    range, nearer the camera than the person is; the feet in view must still count. The old
    placement dropped them: 0.36 .. 0.79 m reported for 0.05 m."""
    cell = zn.load_cell(DEMO)
    x, y = spot
    box = person_box(x, y, head_m)
    axis = np.array(spot) + np.array(side) * (cell.spec.person.radius_m + 0.1 + 0.05)
    pose = tool_pose_at(cell, axis)
    truth = true_separation(cell, x, y, pose)
    got = zn.check_persons(cell, "cam0", box, tool_pose=pose, tool_speed_mps=0.1)
    assert got.tool_separation_m <= truth + 1e-6, (got.tool_separation_m, truth)


@pytest.mark.parametrize("head_m", [0.3, 0.6])
def test_a_crouching_person_just_inside_the_protective_zone_is_found(head_m):
    cell = zn.load_cell(DEMO)
    box = person_box(0.0, 1.1, head_m)  # beyond the robot, 0.1 m outside the 2 x 2 m box
    hits = {h.zone_id for h in zn.check_persons(cell, "cam0", box).hits}
    assert "robot-protective" in hits


def test_a_lying_persons_wide_box_keeps_the_feet_position():
    cell = zn.load_cell(DEMO)
    model = cell.camera_models["cam0"]
    box = person_box(0.6, 0.4, 0.35, width_m=1.8)
    p = occ.place_persons(box, model, 1280, 720)
    assert p.hidden[0] and p.located[0]
    c = occ.camera_centre_m(model)[:2]
    far = float(np.hypot(*(p.far_m[0] - c)))
    assert far >= float(np.hypot(0.6 - c[0], 0.4 - c[1])) - 1e-6
