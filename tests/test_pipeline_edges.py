"""The pipeline's timer steps (``tick``: no new frame) and the operator's confirm-clear, in
detail: what a tick decides with, the alert it raises and its fields (found by mutation testing
of the pipeline: monitor/pipeline/core.py, evidence.py, holds.py)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from monitor.config import demo_cell_path
from monitor.health import CameraHealth, HealthConfig
from monitor.pipeline import Pipeline
from monitor.policy import RUN, PolicyConfig, ResetRequest
from monitor.scene import DemoScene, Figure, draw_figure
from monitor.types import Fault, FrameInfo
from monitor.zones import load_cell

AUTO = PolicyConfig(clear_time=0.2, restart_interlock="auto", frame_timeout=5.0,
                    max_frame_age=5.0)


def empty() -> np.ndarray:
    img = DemoScene().background()
    return img


def inside() -> np.ndarray:
    img = empty()
    feet, head = DemoScene().camera.project(np.array([[0.0, -0.8, 0.0], [0.0, -0.8, 1.75]]))
    draw_figure(img, Figure((float(feet[0]), float(feet[1])), float(feet[1] - head[1])))
    return img


def frame(i: int, t: float) -> FrameInfo:
    return FrameInfo("cam0", i, t, 1280, 720)


def test_confirm_clear_on_a_tick_drops_the_hold_and_its_reset_is_judged(detector, caplog):
    pipe = Pipeline(detector, "cam0", PolicyConfig(clear_time=0.2), load_cell(demo_cell_path()))
    person, nobody = inside(), empty()
    for i in range(3):
        seen = pipe.process(person, frame(i, i / 10), i / 10)
    (tid,) = seen.track_ids
    pipe.process(nobody, frame(3, 0.3), 0.3)  # hidden: a hold, not an empty cell
    (hold,) = pipe.holds["cam0"]
    assert hold.track_id == tid
    with caplog.at_level(logging.WARNING, logger="monitor.pipeline"):
        result = pipe.tick(0.45, reset=ResetRequest("bob", 0.45, "c1", "looked twice",
                                                    confirm_clear=True))
    (alert,) = [a for a in result.alerts if a.kind == "confirm_clear"]
    message = f"operator bob confirmed the cell clear: dropped cam0: {hold.describe()}"
    assert (alert.severity, alert.message, alert.source, alert.time) == \
        ("warning", message, "pipeline", 0.45)
    assert alert.details == {
        "operator": "bob", "request_id": "c1", "note": "looked twice",
        "dropped": [{"camera": "cam0", "person": tid, "track_id": tid,
                     "lost_since": hold.lost_since,
                     "zones": [z.zone_id for z in hold.zones]}]}
    assert message in caplog.text
    assert pipe.holds["cam0"] == ()
    # the reset came with the tick: the policy judged it (the hold was the only cause) and
    # accepted it in that step (before, the tick carried the last frame's lost person)
    assert result.command.reset is not None and result.command.reset.operator == "bob"
    assert result.command.reset.accepted, result.command.reset.message
    assert result.now == 0.45


def _held_pipeline(detector) -> Pipeline:
    """A person seen inside the protective zone (STOP, latched), then gone: a hold."""
    pipe = Pipeline(detector, "cam0", PolicyConfig(clear_time=0.2), load_cell(demo_cell_path()))
    person = inside()
    for i in range(3):
        pipe.process(person, frame(i, i / 10), i / 10)
    pipe.process(empty(), frame(3, 0.3), 0.3)
    assert pipe.holds["cam0"]
    return pipe


def test_one_confirm_clear_between_frames_is_accepted_and_the_cell_runs(detector):
    """`monitor reset --confirm-clear` once, arriving between two frames: accepted in that
    step, every hold dropped, the confirm-clear alert raised (the audit), and the empty cell
    runs after clear_time without another reset."""
    pipe = _held_pipeline(detector)
    result = pipe.tick(0.35, reset=ResetRequest("bob", 0.35, "c1", confirm_clear=True))
    assert result.command.reset.accepted, result.command.reset.message
    assert pipe.holds["cam0"] == ()
    assert [a.kind for a in result.alerts].count("confirm_clear") == 1
    nobody = empty()
    states = [pipe.process(nobody, frame(4 + i, 0.4 + i / 10), 0.4 + i / 10).command.state
              for i in range(6)]
    assert states[-1] == RUN, states


@pytest.mark.parametrize("fault", [
    Fault("selftest_failed", "self-test: the test figure was not found", True, "detector"),
    Fault("camera_blinded", "cam0: contrast too low", True, "cam0")], ids=["detector", "camera"])
@pytest.mark.parametrize("on_tick", [True, False], ids=["tick", "frame"])
def test_a_confirm_clear_with_a_camera_in_fault_is_refused_and_drops_nothing(
        detector, fault, on_tick):
    """A camera in fault shows nothing: an operator's look at its picture cannot confirm the
    cell clear. The confirm-clear is refused, every hold stays, and an alert says why."""
    pipe = _held_pipeline(detector)
    reset = ResetRequest("bob", 0.4, "c1", confirm_clear=True)
    if on_tick:
        result = pipe.tick(0.4, reset=reset, extra_faults=(fault,))
    else:
        result = pipe.process(empty(), frame(4, 0.4), 0.4, reset=reset, extra_faults=(fault,))
    assert result.command.reset is not None and not result.command.reset.accepted
    assert pipe.holds["cam0"], "a hold was dropped"
    (alert,) = [a for a in result.alerts if a.kind == "confirm_clear_refused"]
    assert fault.name in alert.message and "no hold dropped" in alert.message
    assert alert.details["cameras"] == [f"cam0 ({fault.name}: {fault.reason})"]
    assert not [a for a in result.alerts if a.kind == "confirm_clear"]


def test_confirm_clear_with_nobody_held_says_so(detector):
    pipe = Pipeline(detector, "cam0", AUTO, load_cell(demo_cell_path()))
    pipe.process(empty(), frame(0, 0.0), 0.0)
    result = pipe.tick(0.1, reset=ResetRequest("ann", 0.1, "c2", confirm_clear=True))
    (alert,) = result.alerts
    assert alert.message == "operator ann confirmed the cell clear: dropped no lost persons held"
    assert alert.details["dropped"] == []


def test_a_tick_decides_at_its_time_with_the_camera_lost_from_the_last_capture(detector):
    health = CameraHealth(HealthConfig(lost_after_s=1.0), "cam0")
    pipe = Pipeline(detector, "cam0", AUTO, load_cell(demo_cell_path()), health)
    nobody = empty()
    for i in range(4):
        pipe.process(nobody, frame(i, i / 10), i / 10)
    # the last frame was captured at 0.3 s but processed at 0.9 s (a slow decode)
    late = pipe.process(nobody, frame(4, 0.4), 0.9)
    assert late.command.state == "RUN"
    result = pipe.tick(1.45)  # 1.05 s after the capture, 0.55 s after processing
    lost = [f for f in result.faults if f.name == "camera_lost"]
    assert lost and lost[0].stop and lost[0].source == "cam0"
    assert result.command.state == "STOP" and result.changed and result.now == 1.45
    (alert,) = [a for a in result.alerts if a.kind == "camera_lost"]
    assert alert.time == 1.45 and alert.severity == "critical"


def test_a_tick_keeps_the_detector_error_active_without_a_cleared_alert(detector):
    pipe = Pipeline(detector, "cam0", AUTO, load_cell(demo_cell_path()))
    pipe.process(empty(), frame(0, 0.0), 0.0)
    broken = pipe.process(np.zeros((720, 1280), np.uint8), frame(1, 0.1), 0.1)
    assert [a.kind for a in broken.alerts if a.kind.startswith("detector")] == \
        ["detector_error"]
    ticked = pipe.tick(0.15)
    assert ticked.command.state == "STOP"
    assert [a.kind for a in ticked.alerts] == []  # still broken: nothing cleared, no repeat


def test_a_tick_with_a_fresh_pose_is_not_pose_stale(detector):
    policy = PolicyConfig(clear_time=0.2, restart_interlock="auto", frame_timeout=5.0,
                          max_frame_age=5.0, separation_monitoring=True, pose_timeout=0.1)
    pipe = Pipeline(detector, "cam0", policy)
    for i in range(3):
        pipe.process(empty(), frame(i, i / 10), i / 10, pose_time=i / 10)
    fresh = pipe.tick(0.25, pose_time=0.24)
    assert "pose_stale" not in {r.code for r in fresh.command.reasons}
    stale = pipe.tick(0.45, pose_time=0.24)
    assert "pose_stale" in {r.code for r in stale.command.reasons}


def test_one_camera_before_its_first_frame_waits_in_the_start_up_stop_only(detector):
    pipe = Pipeline(detector, "cam0", AUTO, load_cell(demo_cell_path()))
    result = pipe.tick(0.1)
    assert result.command.state == "STOP"
    assert [r.code for r in result.command.reasons] == ["startup"]  # no camera_waiting


def test_a_camera_not_yet_delivering_does_not_hide_another_cameras_person(detector, tmp_path):
    import yaml

    data = yaml.safe_load(demo_cell_path().read_text())
    data["cameras"].append(dict(data["cameras"][0], id="cam1"))
    path = tmp_path / "two.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    pipe = Pipeline(detector, ["cam0", "cam1"], AUTO, load_cell(path))
    result = pipe.process(inside(), FrameInfo("cam1", 0, 0.0, 1280, 720), 0.05)
    waiting = [f for f in result.faults if f.name == "camera_waiting"]
    assert waiting and waiting[0].source == "cam0" and waiting[0].reason == \
        "cam0: no frame processed yet"
    assert "protective_zone" in {r.code for r in result.command.reasons}


def test_an_invalid_zone_file_stops_on_ticks_too(detector):
    pipe = Pipeline(detector, "cam0", AUTO, None, zone_error="cell.yaml: zone 'x': bad")
    pipe.process(empty(), frame(0, 0.0), 0.0)
    result = pipe.tick(0.5)
    assert result.command.state == "STOP"
    assert "zone_invalid" in {r.code for r in result.command.reasons}
