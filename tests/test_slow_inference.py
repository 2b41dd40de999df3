"""A model that is slow only on some frames, through the real service (`monitor run` as a
subprocess, real onnxruntime, a real Zenoh peer on 127.0.0.1): frames with a green marker take
seconds to infer, the others are fast. While that one inference blocks the loop, the bus
heartbeat must say STOP ("stalled") within ``bus.stall_timeout`` plus a heartbeat, never keep
repeating RUN, and the decision on the late frame is a STOP (``frame_late``); one shorter than
``policy.frame_timeout`` recovers by itself. (An inference longer than ``frame_timeout`` is a
latched ``monitor_stalled`` STOP: tests/test_stall.py freezes the whole process for that.)"""

from __future__ import annotations

import time
from itertools import pairwise
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort
import pytest

from monitor.config import demo_cell_path
from monitor.scene import DemoScene
from tests.onnx_models import slow_on_marker
from tests.processes import Service, codes, summary_of, wait_for

FPS = 15
# 8 s of the empty cell, looped: after the slow step (1.5 s quiet, up to 3.6 s measured under
# the suite's own load) the cell must stay clear for the 1 s clearing time before the next
# marker comes round (a 4 s loop left 0.4 s under load: no RUN again)
LOOP_FRAMES = 120
MARKED = range(36, 44)  # 0.5 s of marker: a loaded loop cannot skip it; one slow step
STALL_TIMEOUT = 0.5  # bus.stall_timeout (default)
PERIOD = 0.1  # 1 / bus.heartbeat_hz (default)
SLACK = PERIOD  # the heartbeat thread's own scheduling on a loaded machine
ZONES = f'[zones]\nfile = "{demo_cell_path()}"\n'


def marker_video(path: Path) -> Path:
    """The empty cell (the demo scene's first second, repeated) with a pure green square in
    the centre of ``MARKED`` frames."""
    empty = [image for _, (image, _) in zip(range(15), DemoScene().frames(), strict=False)]
    h, w = empty[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (w, h))
    for i in range(LOOP_FRAMES):
        image = empty[i % len(empty)].copy()
        if i in MARKED:
            image[h // 2 - 90:h // 2 + 90, w // 2 - 90:w // 2 + 90] = (0, 255, 0)  # BGR
        writer.write(image)
    writer.release()
    return path


def slow_model(tmp: Path, base: Path, seconds: float) -> Path:
    """The synthetic model, slow by about ``seconds`` on marked frames on this machine."""
    probe = slow_on_marker(base, tmp / "probe.onnx", 100)
    session = ort.InferenceSession(str(probe), providers=["CPUExecutionProvider"])
    h, w = 288, 416  # the input a 1280x720 frame runs at (a rectangular input)
    plain = np.full((1, 3, h, w), 0.45, np.float32)
    marked = plain.copy()
    marked[:, :, h // 2 - 40:h // 2 + 40, w // 2 - 40:w // 2 + 40] = \
        np.array([0.0, 1.0, 0.0], np.float32)[:, None, None]
    times: dict[str, list[float]] = {"plain": [], "marked": []}
    for name, x in (("plain", plain), ("marked", marked)) * 4:  # the first pair warms up
        start = time.monotonic()
        session.run(None, {"images": x})
        times[name].append(time.monotonic() - start)
    # the quickest of the timed runs: load only ever makes a run slower, never faster
    per_iteration = max(min(times["marked"][1:]) - min(times["plain"][1:]), 0.01) / 100
    return slow_on_marker(base, tmp / "slow.onnx", int(seconds / per_iteration))


def slow_windows(svc: Service, gap_s: float) -> list[tuple[float, float]]:
    """(start, end) on the monotonic clock of each step that spent over ``gap_s`` on a single
    frame: the frame was captured before the previous step's detections went out and its own
    detections came over ``gap_s`` later (no other step ran in between: one loop)."""
    out = []
    dets = list(svc.detections)
    for prev, cur in pairwise(dets):
        frame = cur.get("frame")
        if frame and cur["mono"] - prev["mono"] > gap_s \
                and frame["capture_time"] <= prev["mono"] + PERIOD:
            out.append((prev["mono"], cur["mono"]))
    return out


def assert_stop_during(svc: Service, window: tuple[float, float]) -> list[dict]:
    """Strict: within ``stall_timeout`` + one heartbeat (+ slack) of the last decision a STOP
    is out, and nothing but STOP until the blocked step is over."""
    start, end = window
    limit = start + STALL_TIMEOUT + PERIOD + SLACK
    inside = [c for c in list(svc.commands) if start < c["mono"] < end]
    late_run = [(round(c["mono"] - start, 3), c["state"]) for c in inside
                if c["mono"] > limit and c["state"] != "STOP"]
    assert late_run == [], f"not STOP while one inference blocked: {late_run}; {svc.log()}"
    stops = [c for c in inside if c["state"] == "STOP" and c["mono"] <= limit]
    assert stops, (f"no STOP within {limit - start:.2f} s of the blocked step's start: "
                   f"{[(round(c['mono'] - start, 3), c['state']) for c in inside]}")
    return inside


def _wait_slow_step(svc: Service, gap_s: float, timeout: float) -> tuple[float, float]:
    def gaps():
        dets = list(svc.detections)
        return sorted(round(b["mono"] - a["mono"], 2) for a, b in pairwise(dets))[-5:]
    try:
        return wait_for(lambda: next(iter(slow_windows(svc, gap_s)), None), timeout,
                        f"a step over {gap_s} s on a marked frame", svc)
    except AssertionError as exc:
        raise AssertionError(f"longest detection gaps {gaps()}: {exc}") from None


@pytest.mark.slow
def test_slow_inference_between_stall_timeout_and_frame_timeout_stops_then_recovers(
        tmp_path, synthetic_model):
    # 1.5 s on a quiet machine: over stall_timeout + 0.3 even if the probe ran under load,
    # under frame_timeout (8 s) even when the suite's load makes the step five times slower
    # (a 3 s frame_timeout was overshot once under the full suite)
    model = slow_model(tmp_path, synthetic_model, 1.5)
    video = marker_video(tmp_path / "marked.mp4")
    with Service(tmp_path, model, str(video), ZONES + "[policy]\nframe_timeout = 8.0\n"
                 # max_frame_age 0.6 s: over a plain step at a load of 8 (0.38 s), under the
                 # slow step (over 0.8 s): only the slow step's frame is late
                 'restart_interlock = "auto"\nmax_frame_age = 0.6\n'
                 # the default two threads, as slow_model measured: the slow step must land
                 # between stall_timeout and frame_timeout (one thread under the suite's load
                 # overshot frame_timeout once in 6 runs)
                 "[detector]\nthreads = 2\n",
                 # every frame of the video (no test cap): a marked frame is never skipped
                 camera_lines=f"loop = true\nrealtime = true\nmax_fps = {FPS}\n") as svc:
        start = svc.next_command(0, lambda c: c["state"] == "RUN", 60, "RUN")[0]
        window = _wait_slow_step(svc, STALL_TIMEOUT + 0.3, 30)
        inside = assert_stop_during(svc, window)
        assert any("stalled" in codes(c) for c in inside), summary_of(inside)
        # the decision on the late frame itself is a STOP (it was a RUN: the frame's age was
        # judged when the step began)
        assert any(r.get("fault") == "frame_late" for c in svc.commands for r in c["reasons"]
                   if c["mono"] > window[0]), summary_of(svc.commands)
        # loosely: RUN again after the blocked step without a reset (more STOPs allowed)
        svc.next_command(start, lambda c: c["state"] == "RUN" and c["mono"] > window[1], 30,
                         "RUN again after the slow inference, without a reset")
