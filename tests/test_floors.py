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
from monitor import zones as zn
from monitor.geometry import occlusion as occ
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
    box = person_box(0.3, -1.2, head_m)  # camera side, 0.2 m outside the 2 x 2 m box
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


# ------------------------------------------------------------------ raised floor regions

PLATFORM = [[-0.8, 0.2], [0.8, 0.2], [0.8, 1.8], [-0.8, 1.8]]


def with_platform(height_m: float, points=PLATFORM, platform_id: str = "platform") -> dict:
    data = demo_data()
    data["floors"] = [{"id": platform_id, "name": "Service platform", "points_m": points,
                       "height_m": height_m}]
    return data


def body_distance(cell: zn.Cell, x: float, y: float, z0: float, pose: geo.ToolPose) -> float:
    """Exact distance from the nominal person cylinder standing at (x, y, z0) to the tool."""
    import fcl

    from monitor.zones.prepare import tool_object

    prep = cell.prepared
    h = prep.person.height_m
    body = fcl.CollisionObject(prep.body_cylinder, fcl.Transform(np.array([x, y, z0 + h / 2])))
    return float(fcl.distance(body, tool_object(prep, pose), fcl.DistanceRequest(),
                              fcl.DistanceResult()))


@pytest.mark.parametrize("height_m", [0.3, 0.5, 1.0])
@pytest.mark.parametrize("spot", [(0.3, 0.8), (-0.5, 1.3), (0.0, 0.3)])
def test_a_person_on_a_declared_platform_is_in_the_protective_volume(height_m, spot):
    """Standing on a platform over the robot's protective box: the feet's sight line meets the
    floor metres beyond the platform (the assessor's 2.78 .. 3.72 m on a 1.0 m platform, out
    of the protective volume); declared, the platform holds the feet."""
    x, y = spot
    box = person_box(x, y, 1.75, floor_z_m=height_m)
    cell = zn.parse_cell(with_platform(height_m))
    hits = {h.zone_id for h in zn.check_persons(cell, "cam0", box).hits}
    assert "robot-protective" in hits


def test_undeclared_the_platform_puts_the_person_outside():
    # the finding, kept as a test of the test
    box = person_box(0.3, 0.8, 1.75, floor_z_m=1.0)
    hits = {h.zone_id for h in zn.check_persons(zn.load_cell(DEMO), "cam0", box).hits}
    assert "robot-protective" not in hits


@pytest.mark.parametrize("height_m", [0.3, 0.5, 1.0])
@pytest.mark.parametrize("side", [(1.0, 0.0), (0.0, 1.0), (0.0, -1.0)])
def test_a_person_on_a_platforms_separation_never_exceeds_the_true_one(height_m, side):
    """The tool 0.1 m from a person on the platform (at their hips): the reported separation
    is at most the true one (the old placement said 0.72 .. 3.72 m)."""
    cell = zn.parse_cell(with_platform(height_m))
    x, y = 0.2, 1.0
    axis = np.array((x, y)) + np.array(side) * (cell.spec.person.radius_m + 0.1 + 0.05)
    pose = tool_pose_at(cell, axis, z=height_m + 0.8)
    truth = body_distance(cell, x, y, height_m, pose)
    assert 0.05 < truth < 0.15
    for head_m in (1.75, 0.6):  # standing, crouching on the platform
        box = person_box(x, y, head_m, floor_z_m=height_m)
        got = zn.check_persons(cell, "cam0", box, tool_pose=pose, tool_speed_mps=0.1)
        assert got.tool_separation_m <= truth + 1e-6, (head_m, got.tool_separation_m, truth)


def test_a_person_on_the_floor_beside_a_platform_is_still_placed_on_the_floor():
    """A foot pixel whose sight line crosses a platform keeps its floor position too."""
    cell = zn.parse_cell(with_platform(1.0, points=[[-3.0, -3.0], [3.0, -3.0], [3.0, -2.2],
                                                     [-3.0, -2.2]]))
    box = person_box(0.0, 0.9, 1.75)
    hits = {h.zone_id for h in zn.check_persons(cell, "cam0", box).hits}
    assert "robot-protective" in hits


def test_a_pit_keeps_the_person_standing_in_it():
    """A pit 0.8 m deep beside the protective box: a person in it is farther than the floor
    mapping says, and shorter in the image."""
    cell = zn.parse_cell(with_platform(-0.8, points=[[-0.6, 1.0], [0.6, 1.0], [0.6, 2.0],
                                                      [-0.6, 2.0]], platform_id="pit"))
    x, y = 0.0, 1.2
    box = person_box(x, y, 1.75, floor_z_m=-0.8)
    p = occ.place_persons(box, cell.camera_models["cam0"], 1280, 720,
                          floors=cell.prepared.floors)
    c = occ.camera_centre_m(cell.camera_models["cam0"])[:2]
    assert float(np.hypot(*(p.far_m[0] - c))) >= float(np.hypot(x - c[0], y - c[1])) - 0.02
    assert p.stand_lo_m[0] == -0.8


@pytest.mark.parametrize(("floor", "message"), [
    ({"id": "p1", "points_m": PLATFORM}, r"floor 'p1': missing field 'height_m'"),
    ({"id": "p1", "points_m": PLATFORM[:2], "height_m": 1.0}, r"floor 'p1': points_m"),
    ({"id": "p1", "points_m": PLATFORM, "height_m": "1.0"}, r"floor 'p1': height_m"),
    ({"id": "p1", "points_m": PLATFORM, "height_m": 1.0, "hieght_m": 2},
     r"floor 'p1': unknown field 'hieght_m'"),
    ({"id": "p1", "points_m": PLATFORM, "height_m": 99.0}, r"floor 'p1': height_m"),
    ({"id": "p1", "points_m": [[0, 0], [1, 1], [1, 0], [0, 1]], "height_m": 1.0},
     r"floor 'p1': points_m: .*(cross|intersect)"),
    ({"id": "p1", "points_m": PLATFORM, "height_m": 0.0}, r"floor 'p1': height_m 0"),
    ({"id": "p 1", "points_m": PLATFORM, "height_m": 1.0}, r"not a valid id"),
])
def test_a_malformed_floor_entry_is_a_one_line_error(floor, message, tmp_path):
    import yaml

    from monitor.errors import ConfigError

    data = demo_data()
    data["floors"] = [floor]
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError, match=message) as err:
        zn.load_cell(path)
    assert "\n" not in str(err.value)


def test_floors_change_the_config_hash_and_a_file_without_keeps_its_own():
    plain = zn.parse_cell(demo_data())
    assert zn.load_cell(DEMO).config_hash == plain.config_hash
    raised = zn.parse_cell(with_platform(1.0))
    assert raised.config_hash != plain.config_hash
    renamed = with_platform(1.0)
    renamed["floors"][0]["name"] = "another name"
    assert zn.parse_cell(renamed).config_hash == raised.config_hash


def test_preview_draws_a_platform_at_its_height():
    cell = zn.parse_cell(with_platform(1.0))
    frame = np.full((720, 1280, 3), 128, np.uint8)
    drawn = zn.draw_zones(frame, cell, "cam0")
    plain = zn.draw_zones(frame, zn.load_cell(DEMO), "cam0")
    # the middle of the platform's top, and where the same floor point would be at z = 0 is
    # not what is drawn (the surface is at 1.0 m)
    top = DEMO_CAMERA.project(np.array([[0.0, 1.0, 1.0]]))[0]
    u, v = int(top[0]), int(top[1])
    assert not np.array_equal(drawn[v, u], plain[v, u])
    assert drawn[v, u, 1] > drawn[v, u, 2]  # green-ish: the floor colour
