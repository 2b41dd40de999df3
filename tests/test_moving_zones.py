"""Zones that follow the tool (monitor/zones/moving.py, moving_check.py, docs/moving-zones.md):
moved with each fresh pose (rotation included), grown by S_p at the tool speed, at their
maximum volume when the pose is stale or missing; a standing person and an approaching tool
through the real pipeline; ``zones preview --tool-pose``."""

from __future__ import annotations

import copy
import dataclasses
import math

import cv2
import numpy as np
import pytest

from monitor import cli
from monitor import geometry as geo
from monitor import zones as zn
from monitor.config import demo_cell_path
from monitor.errors import ConfigError
from monitor.zones.moving import ToolState, cell_from_zone, growth_m, transform_points
from monitor.zones.moving_check import placed_zones

PERSON = (-1.0, -2.0)  # wholly in the demo camera's view, inside MAX_VOLUME
MAX_VOLUME = {"shape": "box", "min_m": [-2.0, -3.3, 0.0], "max_m": [2.0, -1.2, 2.2]}
UPRIGHT = (0.0, 0.0, 0.0, 1.0)


def following(zone: dict, **follow) -> dict:
    return {"id": "tool-zone", "kind": "protective", **zone,
            "follow": {"frame": "tool", "max_volume": copy.deepcopy(MAX_VOLUME), **follow}}


def cylinder(radius: float = 0.2, half: float = 0.3) -> dict:
    return {"shape": "cylinder", "center_m": [0.0, 0.0], "radius_m": radius,
            "z_min_m": -half, "z_max_m": half}


def cell_with(*zones: dict, offset: dict | None = None, tracker_frame: dict | None = None,
              tool: bool = True) -> zn.Cell:
    """The demo cell (camera, person model, separation, tool) with only these zones."""
    data = zn.read_cell_data(demo_cell_path())
    data["zones"] = list(zones)
    if offset is not None:
        data["tool"]["offset"] = offset
    if tracker_frame is not None:
        data["tracker_frame"] = tracker_frame
    if not tool:
        del data["tool"]
    return zn.parse_cell(data, demo_cell_path())


def floor_box(cell: zn.Cell, x: float, y: float) -> np.ndarray:
    """A standing person's box whose feet are exactly at (x, y)."""
    px, _ = cell.camera_models["cam0"].project(np.array([[x, y, 0.0], [x, y, 1.75]]))
    (u, v), (_, top) = px
    return np.array([[u - 25, top, u + 25, v]])


def pose(x: float, y: float, z: float = 1.0, yaw_deg: float = 0.0) -> geo.ToolPose:
    return geo.ToolPose((x, y, z), geo.matrix_to_quaternion_xyzw(geo.rpy_to_matrix(0, 0, yaw_deg)),
                        0.0)


def fresh(p: geo.ToolPose | None, speed: float | None = 0.0) -> ToolState:
    return ToolState(p, 0.0, 0.1, speed)


def hit_ids(report) -> set[str]:
    return {h.zone_id for h in report.hits}


# ---------------------------------------------------------------------------- the transform

def test_the_zone_follows_the_pose_rotation_included():
    """Tool 0.1 m along the tracker's z; tracker frame 0.5 m up; pose turned 90 deg about z.
    A point 0.5 m along the tool's x lands on the cell's +y side of the pose."""
    box = {"shape": "box", "min_m": [0.4, -0.1, -0.1], "max_m": [0.6, 0.1, 0.1]}
    cell = cell_with(following(box), offset={"translation_mm": [0, 0, 100],
                                             "given_as": "tool_in_tracker"},
                     tracker_frame={"translation_m": [0.0, 0.0, 0.5]})
    m = cell_from_zone(cell.spec, pose(1.0, 2.0, 1.0, yaw_deg=90))
    assert transform_points(m, np.array([[0.5, 0.0, 0.0]]))[0] == pytest.approx((1.0, 2.5, 1.6))
    (vol, grow, at_max), = placed_zones(cell.prepared, fresh(pose(1.0, 2.0, 1.0, yaw_deg=90)))
    assert not at_max and grow == 0.0
    assert vol.lo == pytest.approx((0.9, 2.4, 1.5)) and vol.hi == pytest.approx((1.1, 2.6, 1.7))


@pytest.mark.parametrize("yaw, inside", [(90, True), (0, False), (-90, False)])
def test_a_person_is_in_the_zone_only_where_the_turned_pose_puts_it(yaw, inside):
    """A box 0.4..0.8 m along the tool's x: pointed at the person (yaw 90 from 0.6 m south of
    them) it covers them; turned away (0 or -90) it does not."""
    box = {"shape": "box", "min_m": [0.4, -0.1, -0.5], "max_m": [0.8, 0.1, 0.5]}
    cell = cell_with(following(box), offset={"given_as": "tool_in_tracker"})
    x, y = PERSON
    rep = zn.check_persons(cell, "cam0", floor_box(cell, x, y),
                           tool_state=fresh(pose(x, y - 0.6, 1.0, yaw_deg=yaw)))
    assert ("tool-zone" in hit_ids(rep)) is inside


# ---------------------------------------------------------------------------- growth

def reference_sp(v_r: float, p: geo.SeparationParams) -> float:
    """ISO/TS 15066 S_p with Z_d = 0 (the person cylinder carries Z_d), written out again."""
    t_s = v_r / p.deceleration_mps2
    return (p.person_speed_mps * (p.reaction_time_s + t_s) + v_r * p.reaction_time_s
            + v_r ** 2 / (2 * p.deceleration_mps2) + p.intrusion_distance_m
            + p.robot_uncertainty_m)


@pytest.mark.parametrize("speed, gap, inside", [
    (0.0, 0.6, False),  # S_p(0) = 0.38 m < 0.6 m
    (0.5, 0.6, True),  # S_p(0.5) = 0.89 m
    (2.0, 1.2, False),  # S_p(2) = 3.18 m, but max_growth_m 1.0 < 1.2 m
    (2.0, 0.9, True),
    (math.nan, 0.9, True),  # a speed that is not a number grows to the maximum
    (None, 0.6, True),  # unknown: robot_speed_default_mps 1.0 (S_p 1.48, capped at 1.0)
])
def test_the_zone_grows_with_the_tool_speed_up_to_max_growth(speed, gap, inside):
    cell = cell_with(following(cylinder(0.1, 0.5), grow_with_speed=True, max_growth_m=1.0))
    prep = cell.prepared
    z = cell.zone("tool-zone")
    v = prep.separation.robot_speed_default_mps if speed is None else speed
    want = 1.0 if math.isnan(v) else min(reference_sp(v, prep.separation), 1.0)
    assert growth_m(z, prep.separation, speed) == pytest.approx(want)
    x, y = PERSON
    # gap between the zone cylinder (r 0.1) and the person's zone cylinder (r 0.3 + Z_d 0.1)
    tool_x = x + 0.1 + 0.4 + gap
    rep = zn.check_persons(cell, "cam0", floor_box(cell, x, y),
                           tool_state=fresh(pose(tool_x, y), speed))
    assert ("tool-zone" in hit_ids(rep)) is inside


def test_without_grow_with_speed_the_zone_keeps_its_size():
    cell = cell_with(following(cylinder(0.1, 0.5)))
    assert growth_m(cell.zone("tool-zone"), cell.prepared.separation, 5.0) == 0.0
    x, y = PERSON
    rep = zn.check_persons(cell, "cam0", floor_box(cell, x, y),
                           tool_state=fresh(pose(x + 0.5 + 0.05, y), 5.0))
    assert not rep.hits


# ---------------------------------------------------------------------------- stale pose

@pytest.mark.parametrize("state", [
    pytest.param(ToolState(pose(3.0, -2.0), 0.2, 0.1, 0.0), id="older-than-timeout"),
    pytest.param(ToolState(pose(3.0, -2.0), math.nan, 0.1, 0.0), id="nan-age"),
    pytest.param(ToolState(pose(3.0, -2.0), None, 0.1, 0.0), id="no-receive-time"),
    pytest.param(ToolState(None, None, 0.1, 0.0), id="no-pose"),
    pytest.param(None, id="no-tool-state"),
    pytest.param(ToolState(geo.ToolPose((3.0, -2.0, 1.0), (0.0, 0.0, 0.0, 0.0), 0.0), 0.0, 0.1,
                           0.0), id="zero-quaternion"),
    pytest.param(ToolState(geo.ToolPose((math.nan, -2.0, 1.0), UPRIGHT, 0.0), 0.0, 0.1, 0.0),
                 id="nan-position"),
])
def test_a_pose_that_is_not_fresh_makes_the_zone_its_maximum_volume(state):
    """The same pose 4 m from the person: fresh, no hit; stale (or unusable), the zone is its
    max_volume, which covers the person."""
    cell = cell_with(following(cylinder()))
    boxes = floor_box(cell, *PERSON)
    assert not zn.check_persons(cell, "cam0", boxes, tool_state=fresh(pose(3.0, -2.0))).hits
    (vol, _, at_max), = placed_zones(cell.prepared, state)
    assert at_max and vol.lo == pytest.approx((-2.0, -3.3, 0.0))
    rep = zn.check_persons(cell, "cam0", boxes, tool_state=state)
    assert hit_ids(rep) == {"tool-zone"}
    assert {h.kind for h in rep.hits} == {"protective"}


def test_a_stale_pose_does_not_hit_a_person_outside_the_maximum_volume():
    cell = cell_with(following(cylinder()))
    rep = zn.check_persons(cell, "cam0", floor_box(cell, 1.8, 1.5),
                           tool_state=ToolState(pose(3.0, -2.0), 5.0, 0.1, 0.0))
    assert not rep.hits


# ---------------------------------------------------------------------------- the zone file

@pytest.mark.parametrize("change, message", [
    (lambda z: z.update(kind="mask"), "only protective and warning zones may follow the tool"),
    (lambda z: z["follow"].update(grow_with_speed=True), "grow_with_speed needs max_growth_m"),
    (lambda z: z["follow"].update(max_growth_m=0.5), "max_growth_m is only for grow_with_speed"),
    (lambda z: z["follow"].pop("max_volume"), "missing field 'follow.max_volume'"),
    (lambda z: z["follow"].update(frame="base"), "unknown frame 'base'"),
    (lambda z: z["follow"]["max_volume"].update(z_min_m=0.0),
     "unknown field 'follow.max_volume.z_min_m'"),
    (lambda z: z["follow"]["max_volume"].update(max_m=[2.0, -1.2, -1.0]),
     "follow.max_volume: z_min >= z_max"),
])
def test_a_malformed_following_zone_gets_a_one_line_error(change, message):
    zone = following(cylinder())
    change(zone)
    with pytest.raises(ConfigError) as err:
        cell_with(zone)
    text = str(err.value)
    assert message in text and "\n" not in text and "tool-zone" in text


def test_flange_frame_needs_the_calibrations_offset_and_a_tool_section():
    zone = following(cylinder(), frame="flange")
    cell = cell_with(zone)  # the demo's offset is the calibration's tracker_in_tool: accepted
    assert cell.prepared.moving
    with pytest.raises(ConfigError, match=r"frame 'flange' needs tool\.offset given_as: "
                                          r"tracker_in_tool"):
        cell_with(zone, offset={"given_as": "tool_in_tracker"})
    with pytest.raises(ConfigError, match="needs the zone file's 'tool:' section"):
        cell_with(following(cylinder()), tool=False)


def test_a_following_zone_leaves_the_config_hash_of_other_files_alone():
    """Files without follow: keep their hash (follow: None is left out of it)."""
    demo = zn.load_cell(demo_cell_path())
    data = zn.read_cell_data(demo_cell_path())
    assert zn.parse_cell(data, demo_cell_path()).config_hash == demo.config_hash
    assert cell_with(following(cylinder())).config_hash != cell_with(
        following(cylinder(0.3))).config_hash


# ---------------------------------------------------------------------------- the pipeline

def _scene_pipeline(detector):
    from monitor.pipeline import Pipeline
    from monitor.policy import PolicyConfig
    from monitor.scene import DemoScene, Figure, draw_figure
    from monitor.types import FrameInfo

    cell = cell_with(following(cylinder(0.2, 0.3)))
    policy = PolicyConfig(clear_time=0.3, restart_interlock="auto", pose_timeout=0.1)
    pipe = Pipeline(detector, "cam0", policy, cell)  # no health: a still scene is the point
    scene = DemoScene()
    background = scene.background()

    def frame(i: int):
        img = background.copy()
        img[::7, ::5] += np.uint8(i % 3)
        feet = scene.camera.project(np.array([[*PERSON, 0.0], [*PERSON, 1.75]]))
        draw_figure(img, Figure((float(feet[0][0]), float(feet[0][1])),
                                float(feet[0][1] - feet[1][1])))
        return img, FrameInfo("cam0", i, i / 10, 1280, 720)

    return cell, pipe, frame


def _reaches(cell: zn.Cell, boxes: np.ndarray, tool_x: float, band_px: float) -> bool:
    """Closed form: the vertical zone cylinder (r 0.2, z 0.7..1.3, axis at (tool_x, y)) meets
    the person's zone cylinder (r 0.4) swept over the floor range the check places them on."""
    from monitor.zones.check import placement

    place = placement(cell.prepared, "cam0", boxes, (0.0, band_px))
    a, b = place.near_m[0], place.far_m[0]
    p = np.array([tool_x, PERSON[1]])
    d = b - a
    t = 0.0 if not d.any() else float(np.clip((p - a) @ d / (d @ d), 0.0, 1.0))
    return float(np.hypot(*(a + t * d - p))) <= 0.2 + 0.4


def test_an_approaching_tool_zone_stops_when_it_reaches_the_standing_person(detector):
    """The tool comes 0.1 m per frame towards a standing person: RUN while the moving zone is
    away from them, STOP in the first frame it reaches the floor range they are placed on."""
    cell, pipe, frame = _scene_pipeline(detector)
    foot = detector.foot_uncertainty_px(1280, 720)
    y = PERSON[1]
    i = 0
    for _ in range(6):  # the tool waits 4 m away while start-up clears
        img, info = frame(i)
        result = pipe.process(img, info, info.capture_time, tool_pose=pose(3.0, y),
                              tool_speed_mps=0.0, pose_time=info.capture_time)
        i += 1
    assert result.command.state == "RUN", result.command.reasons
    assert len(result.persons) == 1
    assert result.zone_report.tool_separation_m is None  # separation monitoring is off
    stopped_at = None
    for k in range(40):
        tool_x = 3.0 - 0.1 * (k + 1)
        img, info = frame(i)
        result = pipe.process(img, info, info.capture_time, tool_pose=pose(tool_x, y),
                              tool_speed_mps=1.0, pose_time=info.capture_time)
        i += 1
        reached = _reaches(cell, result.persons.boxes_px, tool_x, foot)
        if not reached:
            assert result.command.state == "RUN", (tool_x, result.command.reasons)
            continue
        assert result.command.state == "STOP", tool_x
        assert {(r.code, r.zone_id) for r in result.command.reasons} == {
            ("protective_zone", "tool-zone")}
        stopped_at = tool_x
        break
    # far for many frames first; reached before the tool is over them
    assert stopped_at is not None and PERSON[0] < stopped_at < 0.0, stopped_at


def test_with_the_pose_withheld_the_maximum_volume_stops_at_once(detector):
    """The same scene, the tool pose 1 s old (pose_timeout 0.1 s): the zone is its maximum
    volume, which covers the person: a protective_zone STOP from the first frame on, and it
    stays past clear_time."""
    _, pipe, frame = _scene_pipeline(detector)
    for i in range(8):
        img, info = frame(i)
        result = pipe.process(img, info, info.capture_time,
                              tool_pose=pose(3.0, PERSON[1]), tool_speed_mps=0.0,
                              pose_time=info.capture_time - 1.0)
        assert result.command.state == "STOP"
        assert ("protective_zone", "tool-zone") in {(r.code, r.zone_id)
                                                     for r in result.command.reasons}
    img, info = frame(8)  # no pose at all: the same
    result = pipe.process(img, info, info.capture_time)
    assert ("protective_zone", "tool-zone") in {(r.code, r.zone_id)
                                                 for r in result.command.reasons}


# ---------------------------------------------------------------------------- preview

def test_zones_preview_draws_the_zone_at_the_tool_pose(tmp_path, monkeypatch, capsys):
    import yaml

    monkeypatch.chdir(tmp_path)
    data = zn.read_cell_data(demo_cell_path())
    data["zones"] = [following(cylinder(0.3, 0.3))]
    with open("cell.yaml", "w") as f:
        yaml.safe_dump(json_ready(data), f)
    cv2.imwrite("f.png", np.full((720, 1280, 3), 90, np.uint8))
    at = (1.5, 1.5, 1.0)
    args = ("preview", "cell.yaml", "--frame", "f.png")
    assert cli.main(["zones", *args, "--out", "with.png",
                     "--tool-pose", f"{at[0]},{at[1]},{at[2]},0,0,30"]) == 0
    assert cli.main(["zones", *args, "--out", "without.png"]) == 0
    with_pose, without = cv2.imread("with.png"), cv2.imread("without.png")
    cell = zn.load_cell("cell.yaml")
    centre = transform_points(cell_from_zone(cell.spec, pose(*at)), np.zeros((1, 3)))
    (u, v), = cell.camera_models["cam0"].project(centre)[0]
    b, _, r = (int(c) for c in with_pose[round(v), round(u)])
    assert r > 120 and b < 85  # the protective colour's fill
    assert not np.array_equal(with_pose[round(v), round(u)], without[round(v), round(u)])
    # without a pose it is drawn at its maximum volume (the middle of the max box's floor)
    (mu, mv), = cell.camera_models["cam0"].project(np.array([[0.0, -2.25, 0.0]]))[0]
    assert without[round(mv), round(mu)][2] > 120
    with pytest.raises(SystemExit):
        cli.main(["zones", *args, "--out", "x.png", "--tool-pose", "1,2,3"])
    assert "needs six finite numbers" in capsys.readouterr().err


def json_ready(data):
    """Tuples as lists for yaml.safe_dump."""
    if isinstance(data, dict):
        return {k: json_ready(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [json_ready(v) for v in data]
    return data


def test_tool_state_at_measures_the_age_on_the_callers_clock():
    s = ToolState.at(10.0, pose(0, 0), 9.95, 0.1, 0.2)
    assert s.fresh and s.age_s == pytest.approx(0.05)
    assert not dataclasses.replace(s, age_s=0.2).fresh
    assert not ToolState.at(10.0, pose(0, 0), None, 0.1, 0.2).fresh


# ---------------------------------------------------------------------------- mesh zones

@pytest.mark.parametrize("tool_at, inside", [
    ((-1.0, -2.0), True),  # the person wholly inside the moved mesh: no surface contact
    ((-1.0, -2.0 + 2.5), False),  # moved 2.5 m along y: it misses them
])
def test_a_following_mesh_zone_moves_and_contains(tmp_path, tool_at, inside):
    """A closed 3 x 3 x 4 m mesh in the tool frame, centred 1 m below the tool: at a pose over
    the person it contains their whole cylinder (FCL sees no surface contact: the containment
    test must catch it); moved 2.5 m away it misses them."""
    import shutil

    import trimesh

    mesh = trimesh.creation.box(extents=(3.0, 3.0, 4.0))
    mesh.apply_translation((0.0, 0.0, -1.0))
    data = zn.read_cell_data(demo_cell_path())
    folder = tmp_path / "cell"
    folder.mkdir()
    mesh.export(folder / "reach.stl")
    shutil.copy(demo_cell_path(), folder / "cell.yaml")
    data["zones"] = [following({"shape": "mesh", "file": "reach.stl"})]
    cell = zn.parse_cell(data, folder / "cell.yaml")
    rep = zn.check_persons(cell, "cam0", floor_box(cell, *PERSON),
                           tool_state=fresh(pose(*tool_at, 1.5)))
    assert ("tool-zone" in hit_ids(rep)) is inside
