"""Speed and separation monitoring (issue 11): tool speed measured from the pose stream,
the v_max speed scale, T_r from the configuration, fail-safe separation.

The two streams of the findings: positions moving at 1.5 m/s with a zero velocity field, and a
tracker turning at 3 rad/s with the tool 0.25 m away. Both must give the separation and speed
scale of the reference formula (STOP where it says STOP), at the geometry, zone-check and
pipeline level.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from monitor import geometry as geo
from monitor import zones as zn
from monitor.config import demo_cell_path
from monitor.errors import ConfigError
from monitor.pose.otus import OtusSample
from monitor.pose.tool_motion import MotionLimits, ToolMotion, estimate_tool_speed
from monitor.zones import separation as zsep
from tests.helpers import live_frame

ZERO = (0.0, 0.0, 0.0)


def reference_sp(v_r: float, p: geo.SeparationParams, z_d: float) -> float:
    """ISO/TS 15066 S_p written out once more, independently of the code under test."""
    t_s = v_r / p.deceleration_mps2
    return (p.person_speed_mps * (p.reaction_time_s + t_s) + v_r * p.reaction_time_s
            + v_r ** 2 / (2 * p.deceleration_mps2) + p.intrusion_distance_m + z_d
            + p.robot_uncertainty_m)


def sample(t: float, pos=(0.0, 0.0, 1.0), vel=ZERO, q=(0.0, 0.0, 0.0, 1.0),
           omega=ZERO) -> OtusSample:
    return OtusSample(1.0, t, tuple(pos), tuple(vel), ZERO, tuple(q), tuple(omega), ZERO)


def sliding_stream(speed: float, reported: float, n: int = 60, hz: float = 400.0,
                   end=(0.0, 0.0, 1.0)) -> list[OtusSample]:
    """Moving along +x at ``speed``, reporting ``reported`` as its velocity; ends at ``end``."""
    out = []
    for i in range(n):
        t = 1.0 + i / hz
        x = end[0] - speed * (n - 1 - i) / hz
        out.append(sample(t, (x, end[1], end[2]), vel=(reported, 0.0, 0.0)))
    return out


def turning_stream(omega: float, reported: float, n: int = 60, hz: float = 400.0,
                   pos=(0.0, 0.0, 1.0)) -> list[OtusSample]:
    """Turning about the tracker's z axis at ``omega`` rad/s, reporting ``reported``."""
    out = []
    for i in range(n):
        t = 1.0 + i / hz
        a = omega * (t - 1.0)
        out.append(sample(t, pos, q=(0.0, 0.0, math.sin(a / 2), math.cos(a / 2)),
                          omega=(0.0, 0.0, reported)))
    return out


# ---------------------------------------------------------------------------- tool speed


def test_a_stream_moving_at_1_5_m_s_with_zero_velocity_is_measured_and_implausible():
    speed = estimate_tool_speed(sliding_stream(1.5, 0.0))
    assert speed.measured_mps == pytest.approx(1.5, rel=1e-6)
    assert speed.reported_mps == 0.0
    assert speed.speed_mps == pytest.approx(1.5, rel=1e-6)
    assert speed.fault is not None and speed.fault.name == "pose_implausible"
    assert speed.fault.stop and speed.fault.source == "pose"
    # S_p at the measured speed, not at the reported 0 m/s: 2.39 m, not 0.48 m
    p = geo.SeparationParams(reaction_time_s=0.1, intrusion_distance_m=0.2)
    assert geo.protective_separation_m(speed.speed_mps, p, 0.1) == pytest.approx(2.3925, abs=1e-3)


def test_rotation_at_3_rad_s_moves_a_tool_point_0_25_m_away_at_0_75_m_s():
    tool = np.array([[0.25, 0.0, 0.0]])
    speed = estimate_tool_speed(turning_stream(3.0, 0.0), tool)
    # chord over the 50 ms window: 2 r sin(w dt / 2) / dt = 0.7493 m/s
    assert speed.measured_mps == pytest.approx(0.75, abs=0.002)
    assert speed.fault is not None and speed.fault.name == "pose_implausible"
    assert "rad/s" in speed.fault.reason
    honest = estimate_tool_speed(turning_stream(3.0, 3.0), tool)
    assert honest.fault is None
    assert honest.reported_mps == pytest.approx(0.75, rel=1e-9)  # |w x r|
    # the origin alone does not move: the tool points are what counts
    assert estimate_tool_speed(turning_stream(3.0, 3.0)).measured_mps == pytest.approx(0.0,
                                                                                      abs=1e-9)


def test_an_honest_noisy_stream_is_plausible_and_uses_the_larger_speed():
    rng = np.random.default_rng(3)
    stream = [dataclasses.replace(s, position_m=tuple(np.add(s.position_m,
                                                             rng.normal(0, 0.001, 3))))
              for s in sliding_stream(0.8, 0.8, n=200)]
    motion = ToolMotion(MotionLimits(window_s=0.05, history_s=0.2))
    for s in stream:
        motion.add(s)
    assert len(motion.history()) <= 0.2 * 400 + 2  # only the last history_s is kept
    speed = motion.tool_speed()
    assert speed.fault is None
    assert speed.speed_mps >= 0.8 - 1e-9  # never below the reported speed
    assert speed.measured_mps == pytest.approx(0.8, abs=0.06)


def test_a_short_history_falls_back_to_the_unknown_speed():
    speed = estimate_tool_speed(sliding_stream(1.5, 0.0, n=3), unknown_mps=1.0)
    assert speed.measured_mps is None and speed.speed_mps == 1.0


# ---------------------------------------------------------------------------- v_max scale


@settings(max_examples=400, deadline=None)
@given(d=st.floats(0.0, 8.0), v=st.floats(0.0, 3.0), programmed=st.floats(0.05, 3.0),
       v_h=st.floats(0.0, 2.5), t_r=st.floats(0.0, 1.5), a=st.floats(0.2, 10.0),
       c=st.floats(0.0, 1.0), z_d=st.floats(0.0, 0.5), z_r=st.floats(0.0, 0.2))
def test_commanded_speed_never_exceeds_v_max(d, v, programmed, v_h, t_r, a, c, z_d, z_r):
    p = geo.SeparationParams(person_speed_mps=v_h, reaction_time_s=t_r, deceleration_mps2=a,
                             intrusion_distance_m=c, robot_uncertainty_m=z_r,
                             position_uncertainty_m=z_d)
    scale = geo.separation_speed_scale(d, p, programmed, tool_speed_mps=v)
    v_max = geo.max_robot_speed_mps(d, p)
    assert 0.0 <= scale <= 1.0
    assert scale * programmed <= v_max * (1 + 1e-12) + 1e-12
    # the speed allowed really fits: S_p at the commanded speed is within the separation
    if scale > 0:
        assert reference_sp(scale * programmed, p, z_d) <= d + 1e-9
    # the tool already too fast for this separation: STOP
    if reference_sp(v, p, z_d) > d + 1e-9:
        assert scale == 0.0
    # RUN (full speed) only where v_max allows all of the programmed speed
    if scale == 1.0:
        assert v_max >= programmed


def test_the_worst_cases_of_the_finding_now_slow_down():
    p = geo.SeparationParams(reaction_time_s=0.1, intrusion_distance_m=0.2)
    # d = 1.04 m, v = 0.02 m/s: v_max 0.54 m/s, so a 1 m/s programmed speed gets 0.54
    assert geo.separation_speed_scale(1.04, p, 1.0, 0.02) == pytest.approx(
        geo.max_robot_speed_mps(1.04, p), rel=1e-12)
    assert geo.max_robot_speed_mps(1.04, p) == pytest.approx(0.54, abs=0.01)
    # d = 0.5 m at rest: v_max 0.022 m/s, scale 0.022, not 0.3
    assert geo.separation_speed_scale(0.5, p, 1.0, 0.0) == pytest.approx(0.022, abs=0.001)


@pytest.mark.parametrize("bad", [math.nan, -math.inf])
def test_nan_separation_or_speed_is_stop_never_nan(bad):
    p = geo.SeparationParams()
    assert geo.separation_speed_scale(bad, p, 1.0) == 0.0
    assert geo.separation_speed_scale(5.0, p, 1.0, tool_speed_mps=math.nan) == 0.0
    assert geo.separation_speed_scale(5.0, p, math.nan) == 0.0
    assert geo.max_robot_speed_mps(math.nan, p) == 0.0
    assert geo.protective_separation_m(math.nan, p) == math.inf


# ---------------------------------------------------------------------------- T_r and C


def test_reaction_time_is_the_sum_of_the_configured_delays():
    budget = geo.ReactionBudget(frame_interval_s=0.1, max_frame_age_s=0.3, processing_s=0.05,
                                command_ttl_s=0.3, consumer_reaction_s=0.05, pose_age_s=0.1)
    assert budget.total_s() == pytest.approx(0.9)
    assert geo.ReactionBudget().total_s() == pytest.approx(geo.DEFAULT_REACTION_TIME_S)
    with pytest.raises(ValueError, match="command_ttl_s"):
        geo.reaction_time_s(0.1, 0.3, 0.05, -0.3, 0.05)
    text = geo.describe_separation(geo.SeparationParams(reaction_time_s=0.9), 1.0, budget)
    assert "T_r = 0.900 s" in text and "command ttl 0.300" in text
    assert "ISO 13855 whole-body" in text and "C = 0.850 m" in text
    s_full = geo.protective_separation_m(1.0, geo.SeparationParams(reaction_time_s=0.9))
    assert f"S_p = {s_full:.2f} m" in text


def test_intrusion_distance_follows_the_detection_capability():
    assert geo.intrusion_distance_m(None) == 0.85
    assert geo.intrusion_distance_m(70.0) == 0.85
    assert geo.intrusion_distance_m(30.0) == pytest.approx(0.128)
    assert geo.intrusion_distance_m(14.0) == 0.0


def test_with_reaction_time_never_lowers_the_zone_files_value():
    prep = zn.load_cell(demo_cell_path()).prepared  # the demo file says T_r = 0.1 s
    longer = zsep.with_reaction_time(prep, geo.ReactionBudget())
    assert longer.separation.reaction_time_s == pytest.approx(0.8)
    fast = geo.ReactionBudget(0.0, 0.0, 0.0, 0.0, 0.0)
    assert zsep.with_reaction_time(prep, fast).separation.reaction_time_s == 0.1


# ---------------------------------------------------------------------------- zone check


def floor_box(cell: zn.Cell, x: float, y: float) -> list[float]:
    px, _ = cell.camera_models["cam0"].project(np.array([[x, y, 0.0]]))
    u, v = px[0]
    return [u - 30, v - 200, u + 30, v]


def tool_pose_beside(x: float, y: float, gap_m: float) -> geo.ToolPose:
    """Tool pose whose vertical tool cylinder is ``gap_m`` (about) from the nominal person at
    (x, y): person radius 0.3 + tool radius 0.05 (the demo tool)."""
    return geo.ToolPose((x + gap_m + 0.35, y, 1.0), (0.0, 0.0, 0.0, 1.0), 0.0)


@pytest.mark.parametrize("stream, points", [
    pytest.param(sliding_stream(1.5, 0.0), None, id="1.5-m-s-zero-velocity"),
    pytest.param(turning_stream(3.0, 0.0), np.array([[0.25, 0.0, 0.0]]), id="3-rad-s-0.25-m"),
])
def test_zone_check_stops_where_the_reference_says_stop(stream, points):
    cell = zn.load_cell(demo_cell_path())
    prep = cell.prepared
    speed = estimate_tool_speed(stream, points).speed_mps
    boxes = np.array([floor_box(cell, -1.0, -3.0)])
    rep = zn.check_persons(cell, "cam0", boxes, tool_pose=tool_pose_beside(-1.0, -3.0, 1.15),
                           tool_speed_mps=speed)
    # about 1.15 m; the placement may put a short box's person up to ~0.15 m nearer (feet range)
    assert 0.95 < rep.tool_separation_m < 1.25
    p, z_d = prep.separation, prep.person.position_uncertainty_m
    assert rep.required_separation_m == pytest.approx(reference_sp(speed, p, z_d))
    assert rep.required_separation_m > rep.tool_separation_m  # the reference says STOP
    assert rep.separation_speed_scale == 0.0
    # had the reported speed (0) been believed, the old check would have said no STOP
    assert reference_sp(0.0, p, z_d) < rep.tool_separation_m


def test_zone_check_scale_matches_the_formula_when_far():
    cell = zn.load_cell(demo_cell_path())
    prep = cell.prepared
    boxes = np.array([floor_box(cell, -1.0, -3.0)])
    rep = zn.check_persons(cell, "cam0", boxes, tool_pose=tool_pose_beside(-1.0, -3.0, 1.6),
                           tool_speed_mps=0.1)
    params = dataclasses.replace(prep.separation, position_uncertainty_m=0.1)
    expected = geo.separation_speed_scale(rep.tool_separation_m, params,
                                          cell.spec.separation.programmed_speed_mps, 0.1)
    assert 0.0 < rep.separation_speed_scale < 1.0
    assert rep.separation_speed_scale == pytest.approx(expected, rel=1e-12)


def test_a_tool_pose_without_a_tool_or_with_nan_is_stop():
    cell = zn.load_cell(demo_cell_path())
    data = zn.read_cell_data(demo_cell_path())
    del data["tool"]
    no_tool = zn.parse_cell(data, demo_cell_path())
    boxes = np.array([floor_box(cell, -1.0, -3.0)])
    pose = tool_pose_beside(-1.0, -3.0, 3.0)
    rep = zn.check_persons(no_tool, "cam0", boxes, tool_pose=pose, tool_speed_mps=0.0)
    assert rep.separation_speed_scale == 0.0 and rep.tool_separation_m == 0.0
    with pytest.raises(ConfigError, match="separation monitoring needs a 'tool:' section"):
        zsep.require_separation_ready(no_tool)
    zsep.require_separation_ready(cell)
    nan_pose = geo.ToolPose((math.nan, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0), 0.0)
    rep = zn.check_persons(cell, "cam0", boxes, tool_pose=nan_pose, tool_speed_mps=0.0)
    assert rep.separation_speed_scale == 0.0 and rep.tool_separation_m == 0.0
    rep = zn.check_persons(cell, "cam0", boxes, tool_pose=pose, tool_speed_mps=math.nan)
    assert rep.separation_speed_scale == 0.0
    assert not math.isnan(rep.required_separation_m)


def test_tool_points_bound_every_point_of_the_tool():
    prep = zn.load_cell(demo_cell_path()).prepared
    pts = zsep.tool_points_in_tracker(prep)
    assert pts.shape == (8, 3)
    # the cylinder's far end (0.3 m along the tool's z) is inside the points' bounding box
    tip = (prep.tool.offset @ prep.tool.local @ np.array([0.0, 0.05, 0.15, 1.0]))[:3]
    assert np.all(pts.min(axis=0) <= tip) and np.all(tip <= pts.max(axis=0))


# ---------------------------------------------------------------------------- end to end


def test_pipeline_stops_for_a_lying_pose_stream(detector):
    """The real synthetic model sees a person; the tool's stream lies (1.5 m/s, v = 0)."""
    from monitor.health import CameraHealth, HealthConfig
    from monitor.pipeline import Pipeline
    from monitor.policy import PolicyConfig
    from monitor.scene import DemoScene, Figure, draw_figure
    from monitor.types import FrameInfo

    data = zn.read_cell_data(demo_cell_path())
    data["zones"] = []  # only the separation can stop here
    cell = zn.parse_cell(data, demo_cell_path())
    policy = PolicyConfig(clear_time=0.3, restart_interlock="auto", separation_monitoring=True,
                          pose_timeout=5.0)
    pipe = Pipeline(detector, "cam0", policy, cell, CameraHealth(HealthConfig(), "cam0"))
    scene = DemoScene()
    background = scene.background()
    person = (-1.0, -3.0)
    pose = tool_pose_beside(*person, 1.8)  # reference S_p: 2.39 m at 1.5 m/s, 0.48 m at rest
    tool_points = zsep.tool_points_in_tracker(cell.prepared)
    lying = estimate_tool_speed(sliding_stream(1.5, 0.0, end=pose.position_m), tool_points)
    resting = estimate_tool_speed([sample(1.0 + i / 400, pose.position_m) for i in range(60)],
                                  tool_points)
    assert lying.fault is not None and lying.fault.name == "pose_implausible"
    assert resting.fault is None and resting.speed_mps == pytest.approx(0.0, abs=1e-9)

    def frame(i: int, with_person: bool):
        img = live_frame(background, i)
        if with_person:
            feet = scene.camera.project(np.array([[*person, 0.0], [*person, 1.75]]))
            draw_figure(img, Figure((float(feet[0][0]), float(feet[0][1])),
                                    float(feet[0][1] - feet[1][1])))
        return img, FrameInfo("cam0", i, i / 10, 1280, 720)

    def step(i: int, speed: float):
        img, info = frame(i, True)
        return pipe.process(img, info, info.capture_time,
                            tool_pose=dataclasses.replace(pose, time=info.capture_time),
                            tool_speed_mps=speed, pose_time=info.capture_time)

    for i in range(8):  # the person stands there, the tool rests: no separation STOP
        result = step(i, resting.speed_mps)
    assert result.zone_report.tool_separation_m == pytest.approx(1.8, abs=0.35)
    assert "separation" not in {r.code for r in result.command.reasons}
    result = step(8, lying.speed_mps)
    assert result.command.state == "STOP"
    assert "separation" in {r.code for r in result.command.reasons}
    assert result.zone_report.separation_speed_scale == 0.0


# ---------------------------------------------------------------------------- horizon


@pytest.mark.parametrize("pitch", [5, 10, 15])
def test_a_box_above_the_horizon_of_a_tilted_camera_touches_every_volume(pitch):
    """Camera tilted up: a person whose box bottom is above the horizon cannot be placed on the
    floor, so they are in every protective and warning volume and touch the tool."""
    data = zn.read_cell_data(demo_cell_path())
    p = math.radians(pitch)
    fwd = np.array([0.0, math.cos(p), math.sin(p)])
    right = np.array([1.0, 0.0, 0.0])
    r = np.stack([right, np.cross(fwd, right), fwd])
    eye = np.array([0.0, -6.0, 3.0])
    cal = data["cameras"][0]["calibration"]
    cal["rotation"] = r.tolist()
    cal["translation_m"] = (-r @ eye).tolist()
    data["zones"] = [z for z in data["zones"] if z["shape"] != "polygon"]
    for z in data["zones"]:  # tilted up, the camera sees little of their floor: said so
        if z["kind"] in ("protective", "warning"):
            z["unobserved_ok"] = True
    cell = zn.parse_cell(data, demo_cell_path())
    horizon = cell.camera_models["cam0"].horizon_row_px()
    assert 360 < horizon < 720
    above = np.array([[600.0, horizon - 200, 680.0, horizon - 20]])
    below = np.array([[600.0, 500.0, 680.0, 719.0]]) if horizon < 690 else None
    pose = geo.ToolPose((5.0, 5.0, 1.0), (0.0, 0.0, 0.0, 1.0), 0.0)
    rep = zn.check_persons(cell, "cam0", above, tool_pose=pose, tool_speed_mps=0.0)
    volumes = {z["id"] for z in data["zones"] if z["kind"] in ("protective", "warning")}
    assert {h.zone_id for h in rep.hits} == volumes
    assert rep.tool_separation_m == 0.0 and rep.separation_speed_scale == 0.0
    if below is not None:
        xy, valid = cell.camera_models["cam0"].pixel_to_floor(np.array([[640.0, 719.0]]))
        assert valid[0] and xy[0, 1] > -6.0  # floor in front of the camera, not behind it


def test_a_homography_whose_horizon_crosses_its_pairs_is_refused():
    cam = zn.load_cell(demo_cell_path()).camera_models["cam0"]
    r, t = geo.look_at((0, -6.0, 1.5), (0, 0, 1.5))
    level = geo.CameraModel.pinhole(1280, 720, cam.camera_matrix, None, r, t)
    below = np.array([[300.0, 500.0], [900.0, 500.0], [640.0, 700.0], [100.0, 650.0]])
    geo.CameraModel.from_homography(1280, 720, level.homography, below)  # fine
    with pytest.raises(geo.GeometryError, match="horizon"):
        geo.CameraModel.from_homography(1280, 720, level.homography,
                                        np.r_[below, [[640.0, 200.0]]])
