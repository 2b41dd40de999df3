"""The start-up capacity check: a host too slow for its config is refused with one line, not
left to STOP (or flip RUN/STOP on a consumer) all day without saying why."""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib

import pytest
import yaml

from monitor.config import demo_cell_path, parse_config
from monitor.errors import ConfigError
from monitor.service.capacity import (
    CONTENTION,
    PIPELINE_FACTOR,
    TAIL_S,
    CameraDemand,
    Limits,
    assess,
    check,
    decode_time_s,
    measure_detect_s,
)
from monitor.service.setup import check_capacity
from tests.helpers import assert_one_line_error, free_port, run_monitor

DEFAULTS = Limits(frame_timeout=0.5, max_frame_age=0.3, stall_timeout=0.5, lost_after_s=1.0)


def cams(n: int, max_fps: float | None = None) -> list[CameraDemand]:
    return [CameraDemand(f"cam{i}", 1920, 1080, max_fps) for i in range(n)]


def test_four_cameras_at_30_fps_on_a_20_ms_model_are_refused_and_lower_rates_start():
    refused = assess(0.020, cams(4, 30.0), DEFAULTS)
    assert refused.refusal is not None and "\n" not in refused.refusal
    assert "ask for 120 frames/s" in refused.refusal
    frame_s = 0.020 * PIPELINE_FACTOR + decode_time_s(1920, 1080)
    assert math.isclose(refused.frames_per_s, 1 / frame_s)
    assert "fewer cameras" in refused.refusal and "int8" in refused.refusal
    assert "lower max_fps" in refused.refusal
    started = assess(0.010, cams(4, 10.0), DEFAULTS)  # an int8 model at a third of the rate
    assert started.refusal is None
    # cameras in turn: each is processed at most every cycle, here limited by max_fps (0.1 s)
    assert all(math.isclose(f, 10.0) for f in started.processed_fps.values())
    # the newest frame: a whole interval, then the last of 4 frames that arrived together
    step_s = 0.010 * PIPELINE_FACTOR
    latency = TAIL_S + decode_time_s(1920, 1080) + 4 * step_s * (1 + 3 * CONTENTION)
    assert math.isclose(started.latency_s, latency)
    assert all(math.isclose(a, 0.1 + latency) for a in started.frame_age_s.values())
    # the 20 ms model at 5 fps: frames wait 0.2 s for the next one, plus 4 steps slowed by
    # the other cameras' decoding: older than max_frame_age at p99
    slow = assess(0.020, cams(4, 5.0), DEFAULTS)
    assert slow.refusal and "policy.max_frame_age 300 ms (frame_stale would STOP)" in slow.refusal
    assert "cam0, cam1, cam2 and cam3 at a predicted 5 fps per camera" in slow.refusal
    assert "a higher max_fps" in slow.refusal


# benchmarks/capacity.py on a quiet 2-core host, 1080p cameras at 10 fps, 2 threads: the
# measured detection time and the p99 capture-to-decision latency at 1, 2 and 4 cameras
MEASURED = {"int8": (0.0101, {1: 0.0391, 2: 0.0517, 4: 0.1374}),
            "fp32": (0.0191, {1: 0.0534, 2: 0.0657, 4: 0.2285})}


@pytest.mark.parametrize("model", MEASURED)
def test_the_prediction_covers_the_measured_p99_latency_at_four_cameras(model):
    """The former model (a fixed 3 ms read, one step of latency) predicted 117 ms (int8) and
    144 ms (fp32) frame ages at 4 cameras while frames took 137 and 228 ms from capture to
    decision at p99: several 1080p streams decoding beside the detector on 2 cores, and the
    tail. Each predicted latency must cover the measured p99, and the age a whole interval
    more."""
    detect_s, p99 = MEASURED[model]
    for n, measured in p99.items():
        verdict = assess(detect_s, cams(n, 10.0), DEFAULTS)
        assert verdict.latency_s >= measured, (n, verdict.latency_s)
        assert min(verdict.frame_age_s.values()) >= 0.1 + measured, (n, verdict.frame_age_s)


@pytest.mark.parametrize("model", MEASURED)
def test_one_and_two_cameras_that_work_are_not_refused(model):
    detect_s, _ = MEASURED[model]
    for n in (1, 2):
        verdict = assess(detect_s, cams(n, 10.0), DEFAULTS)
        assert verdict.refusal is None and verdict.warnings == (), (n, verdict)
        assert all(math.isclose(f, 10.0) for f in verdict.processed_fps.values())


def test_four_cameras_whose_p99_frames_are_too_old_are_never_ok():
    """int8 at 4 cameras: measured frames are 100 ms (interval) + 137 ms (p99) = 237 ms old
    at a decision. With max_frame_age 0.2 s that is a frame_stale STOP now and then: the
    former model said 117 ms, "ok"."""
    detect_s, p99 = MEASURED["int8"]
    tight = Limits(frame_timeout=0.5, max_frame_age=0.2, stall_timeout=0.5, lost_after_s=1.0)
    assert 0.1 + p99[4] > tight.max_frame_age
    verdict = assess(detect_s, cams(4, 10.0), tight)
    assert verdict.refusal and "policy.max_frame_age" in verdict.refusal
    # fp32 at 4 cameras does not keep 10 fps (9.0 measured): refused at the defaults
    assert assess(MEASURED["fp32"][0], cams(4, 10.0), DEFAULTS).refusal is not None


def test_the_decode_allowance_grows_with_the_pixels():
    hd = assess(0.010, cams(1, 10.0), DEFAULTS)
    uhd = assess(0.010, [CameraDemand("cam0", 3840, 2160, 10.0)], DEFAULTS)
    assert math.isclose(decode_time_s(3840, 2160), 4 * decode_time_s(1920, 1080))
    assert uhd.frame_s - hd.frame_s == pytest.approx(3 * decode_time_s(1920, 1080))
    assert uhd.latency_s > hd.latency_s


def test_a_cycle_longer_than_frame_timeout_is_refused():
    verdict = assess(0.120, cams(4), DEFAULTS)  # 4 x 0.166 s = 0.66 s > 0.5 s
    assert verdict.refusal and "between two frames' decisions (p99, 4 camera(s))" in \
        verdict.refusal
    assert "policy.frame_timeout 500 ms (frame_timeout would STOP" in verdict.refusal


def test_a_max_fps_too_low_for_max_frame_age_is_refused():
    """One camera processed 2 times a second: its newest frame is 0.5 s old before the next
    one, which is a frame_stale STOP every time with max_frame_age 0.3 s."""
    verdict = assess(0.010, cams(1, 2.0), DEFAULTS)
    assert verdict.refusal and "cam0 at a predicted 2 fps: a frame up to 5" in verdict.refusal
    assert "policy.max_frame_age 300 ms (frame_stale would STOP)" in verdict.refusal
    # no frame decided on for 0.5 s and more between two: frame_timeout too
    assert "policy.frame_timeout" in verdict.refusal
    assert "a higher max_fps" in verdict.refusal
    assert assess(0.010, cams(1, 5.0), DEFAULTS).refusal is None  # 0.2 s + one frame


def test_a_step_longer_than_the_bus_stall_timeout_is_refused():
    """Else the bus publishes a "stalled" STOP between two decisions: a consumer flips
    RUN/STOP on every frame (what an integrator saw at 1-2 fps)."""
    limits = Limits(frame_timeout=5.0, max_frame_age=5.0, stall_timeout=0.5, lost_after_s=5.0)
    verdict = assess(0.450, cams(1), limits)
    assert verdict.refusal and "bus.stall_timeout" in verdict.refusal


def test_a_thin_margin_is_a_warning_not_a_refusal():
    verdict = assess(0.080, cams(1), DEFAULTS)  # age 0.112 + 0.141 = 0.253 s of 0.3 s
    assert verdict.refusal is None
    assert any("thin margin" in w and "max_frame_age" in w for w in verdict.warnings)
    assert assess(0.010, cams(1), DEFAULTS).warnings == ()


# the policy and bus limits an integrator loosened for ~1 fps; health.lost_after_s left at 1 s
LOOSE = Limits(frame_timeout=3.0, max_frame_age=3.0, stall_timeout=2.0, lost_after_s=1.0)


def test_two_cameras_at_about_1_fps_are_refused_naming_health_lost_after_s():
    """Issue 29: a host that processes two cameras at ~0.9 fps each passed the check, and
    camera_lost (no frame for lost_after_s 1 s) latched STOP again and again. The refusal
    names the cameras, the predicted rate and the timer."""
    slow_host = assess(0.40, cams(2), LOOSE)  # 0.54 s a frame: each camera every 1.09 s
    assert slow_host.refusal is not None and "\n" not in slow_host.refusal
    assert "cam0 and cam1 at a predicted 0.92 fps per camera" in slow_host.refusal
    assert "a frame every 1.09 s" in slow_host.refusal
    assert "exceeds health.lost_after_s 1.00 s (camera_lost would STOP)" in slow_host.refusal
    # the same with max_fps 0.9 on a fast host: the cameras' rate, not the host, is too low
    capped = assess(0.010, cams(2, 0.9), LOOSE)
    assert "cam0 and cam1 at a predicted 0.9 fps per camera" in capped.refusal
    assert "health.lost_after_s" in capped.refusal and "a higher max_fps" in capped.refusal
    # a lost_after_s that leaves room for the p99 frame age: both start
    fits = dataclasses.replace(LOOSE, lost_after_s=4.0)
    assert assess(0.40, cams(2), fits).refusal is None
    assert assess(0.010, cams(2, 0.9), fits).refusal is None
    near = assess(0.010, cams(2, 0.9), dataclasses.replace(LOOSE, lost_after_s=1.5))
    assert near.refusal is None
    assert any("thin margin" in w and "health.lost_after_s" in w for w in near.warnings)


def test_every_frame_timer_is_checked_at_its_p99_figure():
    """One camera at 2 fps: no frame decided on for 0.5 s and more between two decisions is a
    frame_timeout STOP at 0.5 s (the former check compared the cycle, 18 ms); one step's p99
    (with the tail) against the bus's stall timeout."""
    verdict = assess(0.010, cams(1, 2.0), Limits(frame_timeout=0.5, max_frame_age=5.0,
                                                 stall_timeout=0.5, lost_after_s=5.0))
    assert verdict.frame_gap_s > 0.5
    assert "exceeds policy.frame_timeout 500 ms (frame_timeout would STOP" in verdict.refusal
    step = assess(0.35, cams(1), Limits(5.0, 5.0, 0.5, 5.0))  # 0.48 s a frame, 0.50 s p99
    assert step.frame_s < 0.5 <= step.step_s
    assert "one step (p99) of" in step.refusal and "exceeds bus.stall_timeout 500 ms" in \
        step.refusal


def test_the_start_up_check_of_a_config_refuses_a_lost_after_s_the_rate_cannot_meet(detector):
    """service_setup.check_capacity (what monitor run calls) with a parsed config and the
    real detector: two cameras at max_fps 0.6 are refused naming health.lost_after_s; with
    lost_after_s 4 s the same config passes."""
    text = ('[[camera]]\nid = "cam0"\nmax_fps = 0.6\n[[camera]]\nid = "cam1"\nmax_fps = 0.6\n'
            # limits loose enough for a loaded host's latency (1.7 s p99 at a load of 8)
            '[policy]\nframe_timeout = 5.0\nmax_frame_age = 5.0\n[bus]\nstall_timeout = 2.0\n')
    config = parse_config(tomllib.loads(text))
    with pytest.raises(ConfigError) as refused:
        check_capacity(config, detector, {}, "refuse")
    message = str(refused.value)
    # the cameras' 0.6 fps (a frame every 1.7 s), or less on a host too loaded for that (a
    # load of 8 on 2 cores processed 1.8 frames/s: 2 x 0.9 fps was refused for the host)
    predicted = re.search(r"cam0 and cam1 at a predicted ([\d.]+) fps per camera", message)
    assert "\n" not in message and predicted and float(predicted.group(1)) <= 0.6, message
    assert "exceeds health.lost_after_s 1.00 s (camera_lost would STOP)" in message
    fits = parse_config(tomllib.loads(text + "[health]\nlost_after_s = 4.0\n"))
    verdict = check_capacity(fits, detector, {}, "refuse")
    assert verdict is not None and verdict.refusal is None


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_an_unmeasurable_time_is_an_error_not_a_pass(bad):
    with pytest.raises(ConfigError, match="could not be measured"):
        assess(bad, cams(1), DEFAULTS)


def test_measured_on_a_real_detector_and_the_modes(detector):
    detect_s = measure_detect_s(detector.detect, [(1280, 720)], runs=3)
    assert detect_s is not None and 0 < detect_s < 10
    assert measure_detect_s(detector.detect, [(1280, 720)], stopped=lambda: True) is None
    impossible = cams(4, 1000.0)  # 4000 frames/s: no host does that
    with pytest.raises(ConfigError) as refused:
        check(detector.detect, impossible, DEFAULTS, "refuse")
    assert_one_line = str(refused.value)
    assert "\n" not in assert_one_line and 'capacity_check = "warn"' in assert_one_line
    warned = check(detector.detect, impossible, DEFAULTS, "warn")
    assert warned is not None and warned.refusal is None
    assert "cannot watch the cell in time" in warned.warnings[0]
    assert check(detector.detect, impossible, DEFAULTS, "off") is None


def four_camera_config(tmp_path, model, max_fps: float, extra: str = ""):
    data = yaml.safe_load(demo_cell_path().read_text())
    data["cameras"] = [dict(data["cameras"][0], id=f"cam{i}") for i in range(4)]
    cell = tmp_path / "four.yaml"
    cell.write_text(yaml.safe_dump(data, sort_keys=False))
    cameras = "".join(f'[[camera]]\nid = "cam{i}"\nsource = "synthetic:demo"\n'
                      f'max_fps = {max_fps}\n' for i in range(4))
    config = tmp_path / "monitor.toml"
    config.write_text(cameras + f'[model]\npath = "{model}"\n[zones]\nfile = "{cell}"\n'
                      '[detector]\nthreads = 2\ninput_size = 640\n'
                      f'[bus]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n' + extra)
    return config


@pytest.mark.slow
def test_monitor_run_refuses_a_config_the_host_cannot_serve_and_starts_with_lower_rates(
        tmp_path, synthetic_model):
    config = four_camera_config(tmp_path, synthetic_model, 30)
    assert_one_line_error(run_monitor("run", "--config", config, "--duration", "2"),
                          "this host cannot watch the cell in time", "ask for 120 frames/s")
    # the same cell at a frame every 3.3 s per camera, with limits that allow that rate: starts
    # (limits this loose leave room for ~3 s a frame: the suite beside a mutation run measured
    # 0.93 s a frame, an 11 s p99 gap between decisions and a 2.07 s p99 step, and at a load of
    # 8 on 2 cores 0.54 s a frame refused 4 x 0.5 fps; the pure tests above check the
    # arithmetic at the defaults)
    config = four_camera_config(tmp_path, synthetic_model, 0.3,
                                "stall_timeout = 5.0\n"
                                "[policy]\nframe_timeout = 20.0\nmax_frame_age = 15.0\n"
                                "[health]\nlost_after_s = 15.0\n")
    started = run_monitor("run", "--config", config, "--duration", "3")
    assert started.returncode == 0, started.stderr[-2000:]
    assert "capacity: " in started.stderr and "cam3 0.3 fps" in started.stderr
    # the command line overrides the config's mode: the refused config starts with a warning
    config = four_camera_config(tmp_path, synthetic_model, 30)
    warned = run_monitor("run", "--config", config, "--duration", "2", "--capacity-check",
                         "warn")
    assert warned.returncode == 0, warned.stderr[-2000:]
    assert "cannot watch the cell in time" in warned.stderr


@pytest.mark.parametrize("batch", [False, True], ids=["in-turn", "batched"])
def test_max_fps_caps_how_often_the_service_takes_a_camera(batch):
    """The capacity check counts on [camera] max_fps: the live feed must honour it, one camera
    (in turn) or several (batched), with a real grabber on the demo scene (15 fps)."""
    import itertools
    import threading

    from monitor.frames import LatestFrameGrabber, open_source
    from monitor.service.loop import LiveFeed

    stop = threading.Event()
    grabber = LatestFrameGrabber(open_source("synthetic:demo", "cam0", realtime=True),
                                 stop=stop).start()
    try:
        feed = LiveFeed([grabber], None, None, 0.05, stop, 3.0, alert=None,
                        max_fps={"cam0": 2.0})
        times = []
        while (item := (feed.next_batch() if batch else feed.next())) is not None:
            got, now = item
            frames = got if batch else ([got] if got is not None else [])
            times += [now] * len(frames)
    finally:
        stop.set()
        grabber.stop(timeout=1.0)
    assert 3 <= len(times) <= 7, times  # ~2 a second for 3 s, not the scene's 15
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) >= 0.5 - 0.02
