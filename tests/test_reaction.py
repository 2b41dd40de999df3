"""The reaction-time budget, measured (monitor/geometry/reaction.py): the arithmetic, the crossing
logic of the alert, and `monitor run` alerting at start when its measured budget exceeds its T_r."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import pytest

from monitor.geometry import SeparationParams, protective_separation_m
from monitor.geometry.reaction import (
    ALERT_KIND,
    Allowances,
    MeasuredBudget,
    MeasuredReaction,
    ReactionSink,
    ReactionWatch,
    at_start,
    p99,
)

ALLOW = Allowances(bus_hop_s=0.001, command_ttl_s=0.3, consumer_reaction_s=0.05,
                   pose_age_s=0.1)


def test_budget_sums_measured_parts_and_allowances():
    m = MeasuredReaction("cam0", 0.1, 0.12, ALLOW)
    assert m.total_s == pytest.approx(0.1 + 0.12 + 0.001 + 0.3 + 0.05 + 0.1)
    assert m.to_dict()["measured_s"] == pytest.approx(0.671)


def test_start_estimate_from_capacity_figures():
    # one camera processed at 2 fps, its newest frame at most 0.58 s old at a decision
    start = at_start(0.08, {"cam0": 2.0}, {"cam0": 0.58}, ALLOW)
    assert start["cam0"].frame_interval_s == pytest.approx(0.5)
    assert start["cam0"].capture_to_command_s == pytest.approx(0.58)
    assert start["cam0"].total_s == pytest.approx(0.5 + 0.58 + 0.451)
    assert start["cam0"].source == "start"
    # a camera never processed has no finite budget: exceeded, never "fine"
    assert math.isinf(at_start(0.08, {"cam1": 0.0}, {"cam1": 0.5}, ALLOW)["cam1"].total_s)
    assert ReactionWatch(1.0).verdict(
        at_start(0.08, {"cam1": 0.0}, {"cam1": 0.5}, ALLOW)["cam1"]).exceeded


def test_p99_is_the_pessimistic_rank():
    values = list(range(1, 101))  # 1..100
    assert p99(values) == 99
    assert p99([0.1] * 98 + [5.0, 6.0]) == 5.0  # 2 outliers in 100: the p99 sees one
    assert p99([0.1] * 50 + [5.0]) == 5.0  # 1 in 51 is above 1 %: seen
    assert math.isnan(p99([]))


def test_measured_budget_rolling_p99_per_camera():
    budget = MeasuredBudget(ALLOW, window=50, min_samples=20)
    for i in range(19):
        budget.add("cam0", i * 0.1, i * 0.1 + 0.05)
    assert budget.budgets() == {}  # not enough samples: no live figure yet
    for i in range(19, 60):
        budget.add("cam0", i * 0.1, i * 0.1 + (0.4 if i == 59 else 0.05))
        budget.add("cam1", i * 0.25, i * 0.25 + 0.02)
    live = budget.budgets()
    assert live["cam0"].frame_interval_s == pytest.approx(0.1)
    assert live["cam0"].capture_to_command_s == pytest.approx(0.4)  # one slow frame in 50
    assert live["cam1"].frame_interval_s == pytest.approx(0.25)
    assert live["cam1"].capture_to_command_s == pytest.approx(0.02)
    # the window forgets: 50 fast frames later the slow one is gone
    for i in range(60, 110):
        budget.add("cam0", i * 0.1, i * 0.1 + 0.05)
    assert budget.budgets()["cam0"].capture_to_command_s == pytest.approx(0.05)


def test_watch_alerts_on_crossing_rate_limited_and_says_what_sp_needs():
    params = SeparationParams(reaction_time_s=0.8)
    watch = ReactionWatch(0.8, repeat_s=60.0, params=params, programmed_speed_mps=1.0)
    within = {"cam0": MeasuredReaction("cam0", 0.1, 0.1, ALLOW)}  # 0.651 s
    over = {"cam0": MeasuredReaction("cam0", 0.5, 0.3, ALLOW)}  # 1.251 s
    verdicts, alerts = watch.update(within, 0.0)
    assert not verdicts["cam0"].exceeded and alerts == []
    verdicts, alerts = watch.update(over, 5.0)  # crossing up: one critical alert
    assert verdicts["cam0"].exceeded
    assert [(a.kind, a.severity, a.source) for a in alerts] == [(ALERT_KIND, "critical", "cam0")]
    msg = alerts[0].message
    need = protective_separation_m(1.0, SeparationParams(reaction_time_s=1.251))
    assert "1.251 s" in msg and "0.800 s" in msg and f"{need:.2f} m" in msg
    assert f"{protective_separation_m(1.0, params):.2f} m" in msg
    assert alerts[0].details["measured_s"] == pytest.approx(1.251)
    assert watch.update(over, 10.0)[1] == []  # still over: rate-limited
    assert len(watch.update(over, 65.0)[1]) == 1  # repeated after repeat_s
    _, alerts = watch.update(within, 70.0)  # back within: one info alert
    assert [a.severity for a in alerts] == ["info"]
    assert watch.update(within, 75.0)[1] == []
    assert len(watch.update(over, 76.0)[1]) == 1  # a new crossing is not rate-limited


def test_watch_treats_an_unmeasurable_budget_as_exceeded():
    nan = MeasuredReaction("cam0", math.nan, 0.1, ALLOW)
    assert ReactionWatch(10.0).verdict(nan).exceeded


class _Info:
    def __init__(self, camera_id: str, capture_time: float) -> None:
        self.camera_id, self.capture_time = camera_id, capture_time


class _Frame:
    def __init__(self, camera_id: str, capture_time: float) -> None:
        self.info = _Info(camera_id, capture_time)


class _Step:
    def __init__(self, frame, stalled_s=None) -> None:
        self.frame, self.stalled_s = frame, stalled_s


def test_sink_rechecks_live_and_alerts_on_crossing():
    clock = [0.0]
    alerts, status = [], {}
    watch = ReactionWatch(0.6, repeat_s=60.0)
    sink = ReactionSink(MeasuredBudget(ALLOW, window=40, min_samples=10), watch,
                        alerts.append, status.update, period_s=5.0, clock=lambda: clock[0])
    assert status["reaction_budget"] == {"configured_s": 0.6, "exceeded": False, "cameras": {}}
    for i in range(60):  # 10 fps, commanded 50 ms after capture: 0.1 + 0.05 + 0.451 = 0.601
        clock[0] = i * 0.1 + 0.05
        sink.on_step(_Step(_Frame("cam0", i * 0.1)))
    assert [a.severity for a in alerts] == ["critical"]
    assert status["reaction_budget"]["exceeded"] is True
    cam = status["reaction_budget"]["cameras"]["cam0"]
    assert cam["measured_s"] == pytest.approx(0.601) and cam["source"] == "live"
    # a stalled step's frame is not timed (its command was decided anew)
    before = len(sink.budget._latency["cam0"])
    sink.on_step(_Step(_Frame("cam0", 6.0), stalled_s=1.0))
    assert len(sink.budget._latency["cam0"]) == before


# ------------------------------------------------------------------ monitor run, end to end


def _slow_video(path: Path, fps: float = 1.0, frames: int = 4) -> Path:
    """The empty demo cell at ``fps`` frames a second (looped, real time)."""
    from monitor.scene import DemoScene

    writer = None
    for _, (image, truth) in zip(range(frames), DemoScene().frames(), strict=False):
        assert not truth.persons
        if writer is None:
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                                     (image.shape[1], image.shape[0]))
        writer.write(image)
    writer.release()
    return path


def test_run_alerts_at_start_when_measured_budget_exceeds_tr(tmp_path, synthetic_model):
    """T_r from a tight config (0.3 + 0.3 + 0.05 + ttl 0.3 + consumer 0 + pose 0.05 = 1.0 s),
    a camera that delivers one frame a second: the measured budget is at least 1 s of frame
    interval + 1 s of frame age + ttl, far over T_r on any machine; load only adds to it."""
    from monitor.bus.session import BusConfig, BusKeys, open_session
    from monitor.config import demo_cell_path
    from tests.helpers import free_port
    from tests.processes import Monitor

    video = _slow_video(tmp_path / "slow.mp4")
    peer_port, own_port = free_port(), free_port()
    keys = BusKeys.of("workcell/t24/")
    # the test listens first, so it sees the alert published at start
    session = open_session(BusConfig(cell="t24", instance="test-peer",
                                     listen=(f"tcp/127.0.0.1:{peer_port}",)))
    received: list[dict] = []
    session.declare_subscriber(keys.alert, lambda s: received.append(
        json.loads(s.payload.to_bytes())))
    config = tmp_path / "monitor.toml"
    config.write_text(
        f'[camera]\nsource = "{video}"\nloop = true\nrealtime = true\nmax_fps = 1.0\n'
        f'[model]\npath = "{synthetic_model}"\n'
        f'[zones]\nfile = "{demo_cell_path()}"\n'
        f'[policy]\nseparation_monitoring = true\nframe_timeout = 0.3\nmax_frame_age = 0.3\n'
        f'pose_timeout = 0.05\nrestart_interlock = "auto"\n'
        f'[service]\ncapacity_check = "warn"\ntick_s = 0.05\n'
        f'[reaction]\nconsumer_reaction_ms = 0.0\n'
        f'[bus]\ncell = "t24"\ninstance = "reaction-test"\n'
        f'listen = ["tcp/127.0.0.1:{own_port}"]\nconnect = ["tcp/127.0.0.1:{peer_port}"]\n')
    mon = Monitor(config, own_port, tmp_path / "monitor.log")
    try:
        mon.wait_for(lambda: any(a.get("kind") == ALERT_KIND for a in received), 90,
                     "the reaction_budget alert")
        alert = next(a for a in received if a.get("kind") == ALERT_KIND)
        assert alert["severity"] == "critical" and alert["source"] == "cam0"
        assert "exceeds the T_r 1.000 s that S_p was computed with" in alert["message"]
        assert "separation is too small" in alert["message"]
        log = [json.loads(line) for line in mon.log_path.read_text().splitlines()
               if line.startswith("{")]
        exceeded = [e for e in log if e["event"].startswith("reaction budget EXCEEDED")]
        assert exceeded and exceeded[0]["level"] == "error"
        replies = list(session.get(keys.status, timeout=3.0))
        assert len(replies) == 1 and replies[0].ok is not None
        status = json.loads(replies[0].ok.payload.to_bytes())
        budget = status["reaction_budget"]
        assert budget["configured_s"] == pytest.approx(1.0)
        assert budget["exceeded"] is True
        cam = budget["cameras"]["cam0"]
        assert cam["exceeded"] is True and cam["measured_s"] > 2.0  # >= 1 + 1 + 0.3 + 0.05
    finally:
        mon.close()
        session.close()


# ------------------------------------------------------------------ int8 hint at start


def test_int8_hint_recommends_only_a_checked_file(tmp_path, synthetic_model, detector):
    """A file beside the model named like its int8 build (here a copy of the fp32 model: the
    timing is real onnxruntime either way): recommended only with a record of a passed check
    for exactly this file."""
    import shutil

    from monitor.detector import Detector
    from monitor.detector.quantize import Agreement
    from monitor.service.int8hint import check_passed, int8_hint, record_path, write_record

    model = tmp_path / "m.onnx"
    int8 = tmp_path / "m.int8.onnx"
    shutil.copy(synthetic_model, model)

    def hint():
        return int8_hint(model, detector.detect, lambda p: Detector(p).detect, (640, 360))

    assert hint() is None  # no int8 beside it: nothing to say
    shutil.copy(synthetic_model, int8)
    h = hint()
    assert not h.passed and "no record" in h.message() and "consider" not in h.message()
    agreement = Agreement(22, 46, 46, 46, 1.0, 1.0, 90.0, 50.0)
    write_record(int8, agreement, 0.98, passed=False)  # written with --force
    assert not hint().passed
    write_record(int8, agreement, 0.98, passed=True)
    h = hint()
    assert h.passed and h.fp32_ms > 0 and h.int8_ms > 0
    assert f'consider [model] path = "{int8}"' in h.message()
    assert h.to_dict()["recommended"] is True
    with int8.open("ab") as fh:  # replaced since its check
        fh.write(b"\0")
    passed, why = check_passed(int8)
    assert not passed and "changed" in why
    assert record_path(int8).is_file()
    assert int8_hint(int8, detector.detect, lambda p: Detector(p).detect, (64, 64)) is None
