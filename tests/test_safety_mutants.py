"""Tests that kill the mutants of the safety core and catch the bugs of issue 14.

Each test names the deliberate bug it catches (see docs/policy.md, "Mutation testing"). Public
APIs only, real components.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from monitor import geometry as geo
from monitor import zones as zn
from monitor.bus.session import COMMAND_SCHEMA, CommandWatchdog, Verdict
from monitor.config import demo_cell_path
from monitor.health import CameraHealth, HealthConfig
from monitor.pipeline import Pipeline
from monitor.policy import STOP, PolicyConfig, PolicyInputs, initial_state, step
from monitor.scene import DemoScene
from monitor.types import FrameInfo, ZoneHit, ZoneReport
from monitor.zones import load_cell
from tests.helpers import live_frame

AUTO = PolicyConfig(restart_interlock="auto")


def _running(config: PolicyConfig = AUTO):
    state = initial_state()
    for i in range(12):
        t = i / 10
        state, _ = step(state, PolicyInputs(frame_time=t, zone_report=ZoneReport()), t, config)
    return state, 1.1


def test_bug_warning_zone_speed_scale_zero_stops():
    """Bug 1: ``<=`` -> ``<`` in the policy made a warning zone with speed_scale 0 SLOW at 0."""
    state, t = _running()
    hit = ZoneHit("W1", "warning", 0, 0.0, 1.0)
    _s, cmd = step(state, PolicyInputs(frame_time=t, zone_report=ZoneReport((hit,))), t + 0.01,
                   AUTO)
    assert (cmd.state, cmd.speed_scale) == (STOP, 0.0)


def test_bug_nan_frame_time_is_stale():
    """Bug 2: a NaN frame time must be stale (``now - nan > max_age`` is False)."""
    state, t = _running()
    _s, cmd = step(state, PolicyInputs(frame_time=float("nan"), zone_report=ZoneReport()),
                   t + 0.01, AUTO)
    assert cmd.state == STOP
    assert [r.code for r in cmd.reasons] == ["frame_stale"]


# --- zone check (monitor/zones/check.py) ---------------------------------------------------------


def _share_cell():
    zone = {"id": "z", "kind": "protective", "shape": "polygon", "camera": "cam0",
            "anchor": "share", "min_share": 0.5,
            "points_px": [[100, 100], [400, 100], [400, 400], [100, 400]]}
    return zn.parse_cell({"version": 1, "cameras": [{"id": "cam0", "width": 1280,
                                                     "height": 720}], "zones": [zone]})


def test_bug_share_anchor_at_exactly_min_share_counts():
    """Bug 3: ``>=`` -> ``>`` in the share anchor: a person covering exactly ``min_share`` of
    their box with the zone must count as inside (the zone's pixels are counted: this box
    covers 10000 of 20000 pixels; one column further right covers 9900)."""
    cell = _share_cell()
    at = zn.check_persons(cell, "cam0", np.array([[301.0, 200.0, 501.0, 300.0]]))
    assert [(h.zone_id, h.kind) for h in at.hits] == [("z", "protective")]
    below = zn.check_persons(cell, "cam0", np.array([[302.0, 200.0, 502.0, 300.0]]))
    assert below.hits == ()


def _horizon_cell():
    """A camera at 1.5 m looking level: image row 360 is the horizon. A tool sphere."""
    r, t = geo.look_at((0.0, -6.0, 1.5), (0.0, 0.0, 1.5))
    calibration = {"type": "pinhole", "distortion": [], "rotation": r.tolist(),
                   "translation_m": t.tolist(),
                   "camera_matrix": [[900.0, 0.0, 640.0], [0.0, 900.0, 360.0], [0, 0, 1.0]]}
    return zn.parse_cell({
        "version": 1,
        "cameras": [{"id": "cam0", "width": 1280, "height": 720, "calibration": calibration}],
        "zones": [{"id": "vol-stop", "kind": "protective", "shape": "box",
                   "min_m": [-1, -1, 0], "max_m": [1, 1, 2]}],
        "tool": {"shape": "sphere", "radius_m": 0.05},
    })


def test_bug_unplaceable_person_has_tool_separation_zero():
    """Bug 4: a person who cannot be placed on the floor (feet at or above the horizon) must
    count as touching the tool (separation 0), and the policy then STOPs."""
    cell = _horizon_cell()
    pose = geo.ToolPose((5.0, 5.0, 1.0), (0.0, 0.0, 0.0, 1.0), time=0.0)  # far from the zone
    above = np.array([[600.0, 100.0, 680.0, 300.0]])  # bottom row 300 < horizon row 360
    report = zn.check_persons(cell, "cam0", above, tool_pose=pose, tool_speed_mps=0.5)
    assert report.tool_separation_m == 0.0
    assert report.required_separation_m > 0.0
    state, t = _running()
    _s, cmd = step(state, PolicyInputs(frame_time=t, zone_report=ZoneReport(
        tool_separation_m=report.tool_separation_m,
        required_separation_m=report.required_separation_m)), t + 0.01, AUTO)
    assert cmd.state == STOP and "separation" in [r.code for r in cmd.reasons]
    # the same person placed on the floor far from the tool: a real, positive distance
    placed = zn.check_persons(cell, "cam0", np.array([[600.0, 300.0, 680.0, 500.0]]),
                              tool_pose=pose)
    assert placed.tool_separation_m > 1.0


# --- the consumer watchdog (monitor/bus/session.py CommandWatchdog)
# ---------------------------------------

ALIVE = "workcell/t/safety/alive/mon1"


def _command(**fields) -> bytes:
    body = {"schema": COMMAND_SCHEMA, "seq": 1, "boot": "b1", "state": "RUN",
            "speed_scale": 1.0, "ttl_ms": 300, "instance": "mon1", "reasons": []}
    body.update(fields)
    return json.dumps({k: v for k, v in body.items() if v is not _DROP}).encode()


_DROP = object()


def _live_dog(**kwargs) -> CommandWatchdog:
    dog = CommandWatchdog(**kwargs)
    dog.on_liveliness(ALIVE, True)
    return dog


@pytest.mark.parametrize("payload", [
    pytest.param(_command(schema="workcell.safety.command/0"), id="other_schema"),
    pytest.param(_command(schema=_DROP), id="no_schema"),
    pytest.param(_command(seq=_DROP), id="no_seq"),
    pytest.param(_command(seq="x"), id="seq_not_int"),
    pytest.param(_command(boot=_DROP), id="no_boot"),
    pytest.param(_command(state="GO"), id="unknown_state"),
    pytest.param(_command(state=_DROP), id="no_state"),
    pytest.param(_command(speed_scale=1.01), id="scale_above_1"),
    pytest.param(_command(speed_scale=-0.01), id="scale_below_0"),
    pytest.param(_command(speed_scale="fast"), id="scale_not_a_number"),
    pytest.param(_command(speed_scale=_DROP), id="no_scale"),
    pytest.param(_command(ttl_ms=0), id="ttl_zero"),
    pytest.param(_command(ttl_ms=-5), id="ttl_negative"),
    pytest.param(_command(ttl_ms=_DROP), id="no_ttl"),
    pytest.param(b"[1, 2]", id="not_an_object"),
    pytest.param(b"{bad", id="not_json"),
    pytest.param(b'{"schema": "workcell.safety.command/1", "speed_scale": NaN}', id="nan"),
])
def test_watchdog_refuses_every_malformed_command(payload):
    """Bug 5: a watchdog that stops checking the schema (or any field) lets a stranger's
    message say RUN."""
    dog = _live_dog()
    assert dog.on_command(payload, 1.0) == "invalid"
    assert dog.rejected["invalid"] == 1
    verdict = dog.verdict(1.0)
    assert (verdict.state, verdict.code) == ("STOP", "no_command")


def test_watchdog_accepts_the_edges_of_valid_values():
    dog = _live_dog()
    assert dog.on_command(_command(seq=1, state="SLOW", speed_scale=0.0), 1.0) is None
    assert dog.verdict(1.0).state == "SLOW" and dog.verdict(1.0).speed_scale == 0.0
    assert dog.on_command(_command(seq=2, state="RUN", speed_scale=1.0, ttl_ms=1), 1.0) is None
    assert dog.verdict(1.0).state == "RUN" and dog.verdict(1.0).speed_scale == 1.0
    assert dog.verdict(1.0011).code == "ttl"  # older than 1 ms


def test_watchdog_sequence_instance_ttl_and_liveliness():
    dog = _live_dog(instance="mon1")
    assert dog.on_command(_command(seq=5), 1.0) is None
    assert dog.on_command(_command(seq=9, instance="rogue"), 1.0) == "other_instance"
    assert dog.rejected["other_instance"] == 1 and dog.verdict(1.0).seq == 5
    assert dog.on_command(_command(seq=5), 1.1) == "seq"
    v = dog.verdict(1.1)
    assert (v.state, v.code, v.speed_scale) == ("STOP", "sequence", 0.0)
    assert "5 after 5" in v.reason
    assert dog.on_command(_command(seq=4), 1.1) == "seq" and dog.rejected["seq"] == 2
    assert dog.on_command(_command(seq=6), 1.2) is None
    assert dog.verdict(1.2).state == "RUN" and dog.verdict(1.2).code == ""
    assert dog.on_command(_command(seq=1, boot="b2", ttl_ms=500), 1.5) is None  # restarted
    assert dog.verdict(2.0).state == "RUN"  # exactly ttl old (binary-exact times): valid
    assert dog.verdict(2.0001).code == "ttl"
    dog.on_liveliness(ALIVE, False)
    v = dog.verdict(1.6)
    assert (v.state, v.code) == ("STOP", "liveliness") and "vanished" in v.reason
    other = CommandWatchdog()
    assert other.on_command(_command(seq=1), 1.0) is None
    v = other.verdict(1.0)
    assert (v.state, v.code) == ("STOP", "liveliness") and "not seen" in v.reason
    assert CommandWatchdog(require_liveliness=False).verdict(0.0).code == "no_command"


def test_watchdog_caps_the_ttl_a_command_claims():
    dog = _live_dog(max_ttl_ms=100)
    assert dog.on_command(_command(ttl_ms=5000), 1.0) is None
    assert dog.verdict(1.0625).state == "RUN"
    v = dog.verdict(1.1001)
    assert (v.state, v.code) == ("STOP", "ttl") and "ttl 100 ms" in v.reason
    loose = _live_dog(max_ttl_ms=10_000)
    assert loose.on_command(_command(ttl_ms=300), 1.0) is None
    assert loose.verdict(1.3001).code == "ttl"  # the command's own ttl when below the cap


# --- the pipeline (monitor/pipeline/) -------------------------------------------------------------

PIPE_POLICY = PolicyConfig(clear_time=0.5, restart_interlock="auto")


def _frames(n: int, camera: str = "cam0", fps: float = 10.0, start: int = 0):
    background = DemoScene().background()
    for i in range(start, start + n):
        img = live_frame(background, i)  # a live camera: consecutive frames differ
        yield img, FrameInfo(camera, i, i / fps, 1280, 720)


def test_bug_zone_check_exception_is_a_stop_not_an_empty_cell(detector):
    """Bug 6: an exception in the zone check must STOP (fault ``zone_check_error``), never
    count as an empty cell. Here the cell has no camera of that id: the check raises."""
    pipe = Pipeline(detector, "cam9", PIPE_POLICY, load_cell(demo_cell_path()))
    results = [pipe.process(img, info, info.capture_time)
               for img, info in _frames(12, camera="cam9")]
    assert all(r.command.state == STOP for r in results)
    assert all(r.zone_report is None for r in results)
    faults = {(r.fault, r.source) for r in results[-1].command.reasons if r.code == "fault"}
    assert faults == {("zone_check_error", "zones")}
    assert any(a.kind == "zone_check_error" for a in results[0].alerts)


def test_bug_camera_lost_from_the_pipeline_timer_reaches_the_policy(detector):
    """Bug 7: ``camera_lost`` from the pipeline's own timer (``check_lost`` between frames)
    must reach the policy as a STOP fault, not only the frame timeout."""
    pipe = Pipeline(detector, "cam0", PIPE_POLICY, load_cell(demo_cell_path()),
                    CameraHealth(HealthConfig(lost_after_s=1.0), "cam0"))
    for img, info in _frames(10):
        last = pipe.process(img, info, info.capture_time)
    assert last.command.state == "RUN"
    quiet = pipe.tick(0.9 + 0.99)  # just within lost_after_s: no camera_lost yet
    assert "camera_lost" not in {f.name for f in quiet.faults}
    lost = pipe.tick(0.9 + 1.05)
    assert "camera_lost" in {f.name for f in lost.faults}
    assert lost.command.state == STOP
    assert ("camera_lost", "cam0") in {(r.fault, r.source) for r in lost.command.reasons
                                       if r.code == "fault"}
    assert any(a.kind == "camera_lost" for a in lost.alerts)


def test_pipeline_merges_cameras_towards_danger_and_waits_for_every_camera(detector):
    """A camera that has not delivered keeps the cell in STOP (camera_waiting); the oldest
    camera's frame is the one whose age counts."""
    pipe = Pipeline(detector, ["cam0", "cam1"], PIPE_POLICY)
    results = [pipe.process(img, info, info.capture_time) for img, info in _frames(8)]
    assert all(r.command.state == STOP for r in results)
    assert ("camera_waiting", "cam1") in {(r.fault, r.source)
                                          for r in results[-1].command.reasons}
    # cam1 delivers one frame at 0.0 only: by 0.7 it is the oldest and stale
    img, info = next(_frames(1, camera="cam1"))
    r = pipe.process(img, info, 0.75)
    assert r.command.state == STOP and "frame_stale" in {x.code for x in r.command.reasons}


def test_watchdog_verdicts_exactly():
    """Whole verdicts, not only the state: a STOP verdict that said speed 1.0, or lost the seq
    or the command it refers to, would mislead a controller or its log."""
    dog = _live_dog()
    assert dog.verdict(0.0) == Verdict("STOP", 0.0, "silence: no command received yet",
                                       code="no_command")
    stop = _command(seq=1, state="STOP", speed_scale=0.0)
    assert dog.on_command(stop, 0.0) is None  # received at time 0.0
    assert dog.verdict(0.0) == Verdict("STOP", 0.0, "", 1, json.loads(stop))
    assert dog.verdict(0.5) == Verdict("STOP", 0.0, "silence: last command 500 ms ago "
                                       "(ttl 300 ms)", 1, json.loads(stop), "ttl")
    run = _command(seq=2)
    assert dog.on_command(run, 1.0) is None
    assert dog.verdict(1.0) == Verdict("RUN", 1.0, "", 2, json.loads(run))
    assert dog.verdict(1.5) == Verdict("STOP", 0.0, "silence: last command 500 ms ago "
                                       "(ttl 300 ms)", 2, json.loads(run), "ttl")
    assert dog.on_command(_command(seq=2), 1.1) == "seq"
    assert dog.verdict(1.1) == Verdict("STOP", 0.0, "sequence: seq went backwards (2 after 2)",
                                       2, json.loads(run), "sequence")
    run3 = _command(seq=3)
    assert dog.on_command(run3, 1.2) is None  # a newer one clears the sequence error
    dog.on_liveliness(ALIVE, False)
    assert dog.verdict(1.2) == Verdict("STOP", 0.0, "silence: liveliness token of mon1 vanished",
                                       3, json.loads(run3), "liveliness")
    # a command that names no instance is malformed: dropped, never a RUN
    anonymous = _command(seq=4, instance=_DROP)
    assert dog.on_command(anonymous, 1.3) == "invalid"
    assert dog.verdict(1.3).state == "STOP" and dog.verdict(1.3).speed_scale == 0.0


def test_watchdog_counts_every_rejection():
    dog = _live_dog(instance="mon1")
    for _ in range(2):
        assert dog.on_command(b"{bad", 1.0) == "invalid"
        assert dog.on_command(_command(instance="rogue"), 1.0) == "other_instance"
    assert dog.rejected == {"invalid": 2, "other_instance": 2}
