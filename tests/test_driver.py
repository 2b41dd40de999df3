"""The one loop around the pipeline (``monitor.driver``): replay ticks between frames exactly as
live does, stall detection on the loop's own clock, the detector self-test, reset alerts in
both modes, and "no protective zone, no RUN". Real detector (onnxruntime), real scenes, few
frames: inference is the cost."""

from __future__ import annotations

import itertools
import json
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from monitor.config import demo_cell_path
from monitor.detector import Detector
from monitor.driver import (
    LATE_FAULT,
    STALL_FAULT,
    Driver,
    Step,
    StepInputs,
    has_protective_zone,
    require_protective_zone,
)
from monitor.errors import ConfigError
from monitor.frames import Frame, LatestFrameGrabber, open_source
from monitor.pipeline import Pipeline
from monitor.policy import STOP, PolicyConfig, ResetRequest
from monitor.replay.video import ReplaySettings, VideoFeed, replay
from monitor.scene import DemoScene
from monitor.service.loop import LiveFeed
from monitor.types import Fault, FrameInfo
from monitor.zones import load_cell

POLICY = PolicyConfig()  # frame_timeout 0.5 s, clear_time 1.0 s, manual restart interlock


@pytest.fixture(scope="module")
def empty_cell_image() -> np.ndarray:
    """The demo cell with nobody in it (the person enters later in the scene)."""
    image, truth = next(iter(DemoScene().frames()))
    assert not truth.persons
    return image


def frame_at(image: np.ndarray, seq: int, t: float, camera: str = "cam0") -> Frame:
    return Frame(image, FrameInfo(camera, seq, t, image.shape[1], image.shape[0]))


class Recorder:
    """A sink that keeps every step."""

    def __init__(self) -> None:
        self.steps: list[Step] = []
        self.closed = False

    def on_step(self, step: Step) -> None:
        self.steps.append(step)

    def close(self) -> None:
        self.closed = True


def codes(step: Step) -> set[str]:
    return {r.code for r in step.result.command.reasons}


# --- replay: a gap in the video's timestamps is a frame timeout, as a silent camera is live ----

def test_replay_ticks_between_frames_so_a_timestamp_gap_gives_frame_timeout(
        detector, empty_cell_image):
    cell = load_cell(demo_cell_path())
    times = (0.0, 0.1, 0.8)  # 0.7 s without a frame: longer than frame_timeout (0.5 s)
    frames = [frame_at(empty_cell_image, k, t) for k, t in enumerate(times)]
    rec = Recorder()
    driver = Driver(Pipeline(detector, "cam0", POLICY, cell), [rec])
    driver.run(VideoFeed(frames, 0.05, ()), _Never())
    ticks = [s for s in rec.steps if s.frame is None]
    # a tick every 0.05 s of video time after each frame until the next one is due
    assert [round(s.result.now, 3) for s in ticks] == [0.05] + [
        round(0.1 + 0.05 * k, 3) for k in range(1, 14)]
    timeouts = [s for s in ticks if "frame_timeout" in codes(s)]
    assert timeouts, [(s.result.now, codes(s)) for s in rec.steps]
    first = timeouts[0]
    assert first.result.now > 0.1 + POLICY.frame_timeout
    assert first.result.command.state == STOP and first.result.command.latched
    assert first.index == 1  # the newest processed frame at that moment
    last = rec.steps[-1]  # the frame after the gap does not release the latch
    assert last.frame is not None and last.result.command.state == STOP
    assert last.result.command.latched


def test_replay_without_a_gap_has_no_frame_timeout(detector, empty_cell_image):
    cell = load_cell(demo_cell_path())
    frames = [frame_at(empty_cell_image, k, k * 0.2) for k in range(3)]
    rec = Recorder()
    Driver(Pipeline(detector, "cam0", POLICY, cell), [rec]).run(
        VideoFeed(frames, 0.05, ()), _Never())
    assert not any("frame_timeout" in codes(s) for s in rec.steps)
    assert sum(s.frame is None for s in rec.steps) == 6  # 3 ticks in each 0.2 s gap


class _Never:
    def is_set(self) -> bool:
        return False


# --- stall detection -----------------------------------------------------------------------

class Clock:
    """The driver's monotonic clock, advanced by the test (the process 'freezes')."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_a_loop_gap_beyond_frame_timeout_is_a_latched_stall_stop_and_old_frames_are_dropped(
        detector, empty_cell_image):
    cell = load_cell(demo_cell_path())
    clock, rec = Clock(), Recorder()
    policy = PolicyConfig(restart_interlock="auto")  # the stall fault itself asks for the latch
    driver = Driver(Pipeline(detector, "cam0", policy, cell), [rec],
                    stall_after_s=policy.frame_timeout, clock=clock)
    driver.step(frame_at(empty_cell_image, 0, clock.t), clock.t)
    clock.t += 0.05
    driver.step(None, clock.t)
    assert driver.stalls == 0 and rec.steps[-1].stalled_s is None

    grabbed_before = frame_at(empty_cell_image, 1, clock.t)  # grabbed, then the process froze
    clock.t += 2.0
    step = driver.step(grabbed_before, clock.t)
    assert step.stalled_s == pytest.approx(2.0)
    assert step.frame is None  # the frame from before the gap is never processed
    faults = {f.name: f for f in step.result.faults}
    assert faults[STALL_FAULT].latch and faults[STALL_FAULT].stop
    assert step.result.command.state == STOP
    alerts = {a.kind: a for a in step.result.alerts}
    assert alerts[STALL_FAULT].severity == "critical"
    assert "stalled for 2.00 s" in alerts[STALL_FAULT].message

    clock.t += 0.05  # the frame grabbed before the gap arrives late: dropped too
    late = driver.step(frame_at(empty_cell_image, 2, grabbed_before.info.capture_time), clock.t)
    assert late.frame is None and driver.stalls == 1
    clock.t += 0.05
    fresh = driver.step(frame_at(empty_cell_image, 3, clock.t), clock.t)
    assert fresh.frame is not None and fresh.result.command.state == STOP


class FreezingClock(Clock):
    """Jumps ``by`` seconds at its ``at``-th reading: the process froze inside a step."""

    def __init__(self, at: int, by: float) -> None:
        super().__init__()
        self.calls, self.at, self.by = 0, at, by

    def __call__(self) -> float:
        self.calls += 1
        if self.calls == self.at:
            self.t += self.by
        return self.t


def test_a_freeze_inside_a_step_never_publishes_the_command_decided_before_it(
        detector, empty_cell_image):
    cell = load_cell(demo_cell_path())
    clock, rec = FreezingClock(at=5, by=2.0), Recorder()  # readings: start, done, end; start...
    policy = PolicyConfig(restart_interlock="auto")
    driver = Driver(Pipeline(detector, "cam0", policy, cell), [rec],
                    stall_after_s=0.5, clock=clock)
    driver.step(frame_at(empty_cell_image, 0, clock.t), clock.t)  # readings 1-3
    t = clock.t + 0.05
    clock.t = t
    step = driver.step(frame_at(empty_cell_image, 1, t), t)  # 4: start, 5: done (+2 s)
    assert step.stalled_s == pytest.approx(2.0)
    assert step.frame is not None and step.result.persons is not None  # detections kept
    assert step.result.now == pytest.approx(t + 2.0)  # decided after the freeze
    assert step.result.command.state == STOP
    assert STALL_FAULT in {f.name for f in step.result.faults}


def test_a_frame_already_old_at_the_step_start_and_a_short_step_is_frame_late(
        detector, empty_cell_image):
    """frame_late judges the frame's age when its step ends, not the step's duration: a frame
    just under max_frame_age at the start (the policy's own frame_stale check passes) and a
    step of 0.1 s (far from any stall) hands on a decision about a cell older than
    max_frame_age."""
    cell = load_cell(demo_cell_path())
    clock, rec = FreezingClock(at=5, by=0.1), Recorder()  # the 2nd step's "done" reading
    policy = PolicyConfig(restart_interlock="auto")
    driver = Driver(Pipeline(detector, "cam0", policy, cell), [rec],
                    stall_after_s=0.5, clock=clock)
    first = driver.step(frame_at(empty_cell_image, 0, clock.t), clock.t)  # readings 1-3
    assert LATE_FAULT not in codes_of_faults(first)
    clock.t += 0.05
    age_at_start = policy.max_frame_age - 0.05
    step = driver.step(frame_at(empty_cell_image, 1, clock.t - age_at_start), clock.t)
    assert step.stalled_s is None  # 0.1 s is no stall
    assert "frame_stale" not in {r.code for r in step.result.command.reasons}
    late = [f for f in step.result.faults if f.name == LATE_FAULT]
    assert late, f"no {LATE_FAULT} fault: {step.result.faults}"
    assert late[0].stop and "when its step ended" in late[0].reason, late
    assert step.result.command.state == STOP
    assert step.frame is not None and step.result.persons is not None  # detections kept


def codes_of_faults(step: Step) -> set[str]:
    return {f.name for f in step.result.faults}


class FreezingSink(Recorder):
    """Freezes the process (moves ``clock`` on by ``by`` s) while publishing its ``at``-th step:
    a SIGSTOP that lands in the sinks, after the decision."""

    def __init__(self, clock: Clock, at: int, by: float) -> None:
        super().__init__()
        self.clock, self.at, self.by = clock, at, by

    def on_step(self, step: Step) -> None:
        super().on_step(step)
        if len(self.steps) == self.at:
            self.clock.t += self.by


def test_a_freeze_while_the_sinks_publish_is_a_stall_at_the_next_step(
        detector, empty_cell_image):
    """Found on a loaded machine: the process stopped while publishing a step, and the loop's
    gap was measured from after the sinks, so the freeze went unseen (only the frame's age
    gave a STOP, without the stall alert and with the old frame processed)."""
    clock = Clock()
    sink = FreezingSink(clock, at=2, by=2.0)
    policy = PolicyConfig(restart_interlock="auto")
    driver = Driver(Pipeline(detector, "cam0", policy, load_cell(demo_cell_path())), [sink],
                    stall_after_s=0.5, clock=clock)
    driver.step(frame_at(empty_cell_image, 0, clock.t), clock.t)
    clock.t += 0.05
    grabbed = frame_at(empty_cell_image, 1, clock.t)
    driver.step(grabbed, clock.t)  # frozen for 2 s while its command goes out
    before = frame_at(empty_cell_image, 2, clock.t - 2.0 + 0.01)  # grabbed before the freeze
    step = driver.step(before, clock.t)
    assert step.stalled_s == pytest.approx(2.0)
    assert step.frame is None  # the frame grabbed before the freeze is dropped
    assert STALL_FAULT in {f.name for f in step.result.faults}
    assert step.result.command.state == STOP and driver.stalls == 1
    # live steps carry their decision time: the bus refuses to send one that waited too long
    times = [s.decided_at for s in sink.steps]
    assert None not in times and times == sorted(times) and times[1] < times[2] - 1.9


def test_no_stall_detection_before_the_first_frame_or_in_replay(detector, empty_cell_image):
    clock = Clock()
    driver = Driver(Pipeline(detector, "cam0", POLICY, None), [],
                    stall_after_s=0.5, clock=clock)
    driver.step(None, clock.t)
    clock.t += 3.0  # model warm-up, camera opening: no frame processed yet
    driver.step(None, clock.t)
    assert driver.stalls == 0
    replay_driver = Driver(Pipeline(detector, "cam0", POLICY, None), [], clock=clock)
    replay_driver.step(frame_at(empty_cell_image, 0, 0.0), 0.0)
    clock.t += 3.0
    replay_driver.step(frame_at(empty_cell_image, 1, 0.1), 0.1)
    assert replay_driver.stalls == 0


# --- self-test, reset alerts ---------------------------------------------------------------

class SelfTestFails(Detector):
    """The real detector whose self-test reports a fault (as h5's self_test does on a model
    that no longer finds the reference person)."""

    calls = 0  # per detector: a class-wide count would carry over a second run in one process

    def self_test(self):
        self.calls += 1
        return Fault("detector_self_test", "reference person not found", True, "detector")


def test_self_test_runs_at_start_then_in_the_gaps_and_its_fault_stops(
        synthetic_model, empty_cell_image):
    """At the first step (a frame's), then on the first timer tick once due, and on a frame
    step only when a whole period overdue: a frame never waits for the self-test's inference
    while the loop has a gap to run it in. Its fault holds the STOP at every step."""
    detector = SelfTestFails(synthetic_model)
    rec = Recorder()
    driver = Driver(Pipeline(detector, "cam0", POLICY, None), [rec], self_test_period_s=1.0)
    calls = []
    assert not driver.checks_due(None)  # before any step: the first step runs it anyway
    for k, (t, is_frame) in enumerate([(0.0, True), (0.5, True), (1.0, True), (1.1, False),
                                        (1.6, True), (2.2, True), (2.5, True), (3.1, True),
                                        (3.2, False)]):
        driver.step(frame_at(empty_cell_image, k, t) if is_frame else None, t)
        calls.append(detector.calls)
        if t == 1.6:  # the next is due at 2.1 (the tick at 1.1 + 1 s): the feed is told then
            assert not driver.checks_due(2.09) and driver.checks_due(2.1)
    # 0.0 start; 1.0 a frame step, due but not overdue: waits; 1.1 the tick: runs (next 2.1);
    # 2.2 and 2.5 frame steps, due, not overdue; 3.1 a whole period overdue: runs on the frame
    assert calls == [1, 1, 1, 2, 2, 2, 2, 3, 3]
    assert all("detector_self_test" in {f.name for f in s.result.faults} for s in rec.steps)
    assert rec.steps[-1].result.command.state == STOP


class CountsSelfTests(Detector):
    """The real detector; its self-test passes and notes whether it ran in a frame's step or
    in a timer tick (``at``: the recorder's step count when it ran, that step is the next)."""

    def __init__(self, *args, recorder, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.recorder = recorder
        self.at: list[int] = []

    def self_test(self):
        self.at.append(len(self.recorder.steps))
        return None


class FeedWithoutBus(LiveFeed):
    """The service's live feed (real grabber, real waits) with no resets, pose or bus."""

    def inputs(self, now: float) -> StepInputs:
        return StepInputs()


def test_the_live_loop_runs_the_self_test_in_the_gap_before_the_next_frame(
        synthetic_model, empty_cell_image, tmp_path):
    """A 5 fps camera and a loop whose own ticks (every 0.5 s without a frame) never come:
    the self-test still runs in a tick of its own, taken while no frame waits, never in a
    frame's step in front of its inference (before, it ran in a frame's step every time)."""
    video = tmp_path / "five-fps.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 5.0,
                             (empty_cell_image.shape[1], empty_cell_image.shape[0]))
    for _ in range(20):  # 4 s
        writer.write(empty_cell_image)
    writer.release()
    rec = Recorder()
    detector = CountsSelfTests(synthetic_model, recorder=rec)
    stop = threading.Event()
    grabber = LatestFrameGrabber(open_source(str(video), "cam0", realtime=True, stop=stop),
                                 stop=stop).start()
    try:
        feed = FeedWithoutBus([grabber], None, None, 0.5, stop, 3.5, alert=None)
        Driver(Pipeline(detector, "cam0", POLICY, None), [rec],
               self_test_period_s=0.4).run(feed, stop)
    finally:
        stop.set()
        grabber.stop(timeout=2.0)
    frames = sum(s.frame is not None for s in rec.steps)
    in_ticks = [k for k in detector.at[1:] if rec.steps[k].frame is None]
    assert frames >= 8, f"{frames} frames in 3.5 s of a 5 fps video"
    # ~7 periods; a frame step runs it only a whole period overdue (the loop never idled)
    assert len(detector.at) >= 4 and len(in_ticks) >= 2, (
        f"self-tests at steps {detector.at}, {len(in_ticks)} of them in a tick")


def test_reset_outcomes_raise_alerts_in_replay_too(detector, empty_cell_image):
    rec = Recorder()
    driver = Driver(Pipeline(detector, "cam0", POLICY, None), [rec])
    driver.step(frame_at(empty_cell_image, 0, 0.0), 0.0,
                StepInputs(reset=ResetRequest("ops", 0.0, "r1")))
    kinds = {a.kind: a for a in rec.steps[-1].result.alerts}
    assert kinds["reset_refused"].details["request_id"] == "r1"
    # an operator's act, not a camera's finding: the source says "reset", never "cam0"
    assert kinds["reset_refused"].source == "reset"
    assert kinds["reset_refused"].details["operator"] == "ops"


def test_driver_closes_every_sink_even_when_one_fails():
    class Broken(Recorder):
        def close(self) -> None:
            raise OSError("disk full")
    first, broken = Recorder(), Broken()
    driver = Driver.__new__(Driver)
    driver.sinks = [first, broken]
    with pytest.raises(OSError, match="disk full"):
        driver.close()
    assert first.closed


# --- no protective zone, no RUN ------------------------------------------------------------

def cell_without_protective(tmp_path: Path) -> Path:
    text = demo_cell_path().read_text().replace("kind: protective",
                                                "kind: protective\n    enabled: false")
    path = tmp_path / "no-protective.yaml"
    path.write_text(text)
    return path


def test_a_cell_without_an_enabled_protective_zone_is_refused_unless_allowed(tmp_path):
    demo = load_cell(demo_cell_path())
    assert has_protective_zone(demo)
    cell = load_cell(cell_without_protective(tmp_path))
    assert not has_protective_zone(cell) and not has_protective_zone(None)
    with pytest.raises(ConfigError, match=r"no enabled protective zone.*allow_no_protective"):
        require_protective_zone(cell, False, "cell.yaml")
    with pytest.raises(ConfigError, match="no zone file is given"):
        require_protective_zone(None, False, "")
    require_protective_zone(cell, True, "cell.yaml")  # said explicitly: accepted


def test_replay_refuses_a_cell_without_protective_zone(tmp_path, detector):
    cell = load_cell(cell_without_protective(tmp_path))
    video = tmp_path / "v.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10, (1280, 720))
    writer.write(np.zeros((720, 1280, 3), np.uint8))
    writer.release()
    settings = ReplaySettings(out_dir=tmp_path / "out", annotate=False, progress=False)
    with pytest.raises(ConfigError, match="no enabled protective zone"):
        replay(video, detector, cell, settings)
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_replay_summary_counts_state_and_reason_changes_apart(tmp_path, detector,
                                                              empty_cell_image):
    video = tmp_path / "v.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 5,
                             (empty_cell_image.shape[1], empty_cell_image.shape[0]))
    for _ in range(8):  # 1.6 s of an empty cell: startup STOP, clearing, RUN
        writer.write(empty_cell_image)
    writer.release()
    out = tmp_path / "out"
    settings = ReplaySettings(out_dir=out, annotate=True, progress=False, reset_at=(0.4,),
                              health=None)  # the same image 8 times is a frozen camera
    summary = replay(video, detector, load_cell(demo_cell_path()), settings)
    events = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
    commands = [e for e in events if e["type"] == "command"]
    states = [c["state"] for c in commands]
    transitions = sum(a != b for a, b in itertools.pairwise(states)) + 1
    assert summary.state_changes == transitions
    assert summary.reason_changes == len(commands) - transitions
    assert summary.command_changes == len(commands)
    assert summary.ticks == 7 * 3  # 0.2 s between frames: ticks at +0.05, +0.10, +0.15
    assert [e["kind"] for e in events if e["type"] == "alert"] == ["reset_refused"]
    # the alert's details as the bus carries them: who asked, which request
    (refused,) = [e for e in events if e["type"] == "alert"]
    assert refused["details"]["operator"] == "replay" and refused["details"]["request_id"]
    assert all(c["describe"].startswith(c["state"]) or "LATCHED" in c["describe"]
               for c in commands)
    # the annotated video: every frame, H.264 where PyAV is installed
    cap = cv2.VideoCapture(str(out / "annotated.mp4"))
    try:
        assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 8
        fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode()
    finally:
        cap.release()
    pytest.importorskip("av")
    assert summary.video_codec.startswith("H.264") and fourcc in ("avc1", "h264", "H264")


# --- sinks and CLI helpers -------------------------------------------------------------------

def test_events_sink_writes_a_reset_possible_event(tmp_path, detector, empty_cell_image):
    from monitor.replay.video import EventsSink

    rec = Recorder()
    driver = Driver(Pipeline(detector, "cam0", POLICY, None), [rec])
    step = driver.step(frame_at(empty_cell_image, 0, 0.0), 0.0)
    sink = EventsSink(tmp_path)
    sink.on_step(Step(step.result, step.frame, 0, reset_possible=True))
    sink.close()
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    possible = [e for e in events if e["type"] == "reset_possible"]
    assert possible == [{"type": "reset_possible", "frame": 0, "time_s": 0.0,
                         "describe": possible[0]["describe"]}]
    assert possible[0]["describe"].startswith("STOP")


def test_render_progress_is_silent_when_not_a_terminal(capsys):
    from monitor.cli.run import render_progress

    assert list(render_progress(iter(range(8)), 8)) == list(range(8))
    assert capsys.readouterr().err == ""


def test_demo_with_a_missing_zone_file_is_a_one_line_error(tmp_path):
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "monitor", "demo", "--zones",
                           str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.splitlines()[-1] == f"monitor: error: {tmp_path / 'cell.yaml'}: " \
        "no such zone file"
