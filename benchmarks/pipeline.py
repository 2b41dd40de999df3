"""Whole-pipeline benchmark on a 1080p video at 416: throughput against bare inference, and the
latency from frame capture to command published.

Run: .venv/bin/python benchmarks/pipeline.py [--seconds 12] [--fps 15] [--threads 2] [--int8]
     [--square] (the 416x416 input instead of the 416x288 rectangle a 16:9 frame runs at)
     [--backends all | auto | 'onnxruntime fp32,openvino bf16,openvino int8']

``--backends all`` runs every pass below once per backend and precision this host has (for the
fp32 and the int8 model: onnxruntime, OpenVINO fp32/bf16/int8 with the ``[openvino]`` extra,
...) and once with what ``[detector] backend = "auto"`` chooses, and prints their rows side by
side (monitor/detector/runners.py). "Bare inference" is then that backend's ``runner.run``.

The video is the demo walk (the person enters the warning and the protective zone) rendered at
1280x720 and scaled to 1920x1080, with the demo cell's zones and calibration scaled to match, so
zones, health and policy do their real work. The passes, in one run:

1. Throughput, decode inline (as replay): per frame, read + decode the next frame and
   ``Pipeline.process`` it (detector, zones, health, policy; no annotation, no bus), and a bare
   ``session.run`` on the same input tensor, interleaved so both see the same machine load.
   Target: pipeline fps / bare inference fps >= 0.85 for the backend that runs, and the fixed
   path (every stage but inference: read+decode, preprocess, decode, zones, health, policy)
   under 2 ms a 1080p frame (the row "fixed path").
   Each throughput pass starts as the service's loop does, with what start-up built frozen
   out of the garbage collector (``settle_heap``; ``--no-settle-heap``: without), and the
   inline pass reports the collections that still land in it.
2. Throughput, decode in a reader thread (as the live service's grabber): the same pipeline fed
   from a 2-frame queue.
2b. Throughput through the driver (``monitor.driver.Driver`` with the replay feed, ticks between
   frames, the summary sink): what `monitor replay` costs over bare ``Pipeline.process`` calls
   (the loop before the driver was exactly such a hand-written loop).
3. Latency, live: the video paced at its frame rate through ``LatestFrameGrabber`` into the
   service's driver loop (``Driver`` + ``LiveFeed`` + ``ServiceSink``) with a real
   ``SafetyBus`` on tcp/127.0.0.1 and a subscriber session. Latency = when
   ``publish_command`` returned - the frame's capture stamp (both monotonic); and, for
   commands that changed (the ones put on the wire at once), capture to the subscriber's
   callback. Target: median <= median inference + 5 ms.
4. Bare inference paced like the camera: ``session.run`` alone, once per frame interval, on the
   same tensor, with nothing else in the process running. Its p99 is the tail the model and the
   host give before the monitor adds anything: onnxruntime's second intra-op thread sleeps
   between frames, and when the host does not run it at once the frame runs at one-thread
   speed. The monitor's own share of the tail is capture -> command p99 - this p99.
5. The fixed path alone (``fixed_path_cpu``): the first 90 frames again with each frame's model
   outputs replayed through the runner seam instead of running the model, in CPU time, which
   a loaded host's waits do not inflate: the main thread's per stage, and the decoder's
   worker threads' apart (they decode ahead while the main thread runs the pipeline, so the
   process's CPU over a frame's pipeline span holds decoding too). ``--fixed-only`` runs
   only this pass (a quick before/after on a shared host).
"""

from __future__ import annotations

import argparse
import builtins
import contextlib
import gc
import itertools
import json
import logging
import math
import queue
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from monitor.models import synthetic

from monitor.bus.session import BusConfig, SafetyBus, open_session
from monitor.config import MonitorConfig, demo_cell_path
from monitor.detector import Detector, DetectorConfig, Letterboxer, letterbox
from monitor.detector.envelope import for_detector
from monitor.driver import Driver, settle_heap
from monitor.frames import LatestFrameGrabber, PacedSource, VideoFileReader
from monitor.health import CameraHealth, HealthConfig
from monitor.health.build import camera_health, inplace_check
from monitor.health.objects import ZoneObjects
from monitor.pipeline import Pipeline
from monitor.pipeline import core as pipeline_core
from monitor.replay.video import ReplaySummary, SummarySink, VideoFeed
from monitor.scene import DemoScene, write_video
from monitor.service.loop import LiveFeed, ServiceSink
from monitor.service.metrics import Metrics
from monitor.zones import Cell, parse_cell, read_cell_data

SIZE = (1920, 1080)
SCALE = 1.5  # 1280x720 -> 1920x1080


def make_video(path: Path, seconds: float, fps: float = 15.0) -> int:
    scene = DemoScene(fps=fps)
    n = round(seconds * scene.fps)
    frames = ((cv2.resize(img, SIZE, interpolation=cv2.INTER_LINEAR), t)
              for img, t in itertools.islice(scene.frames(), n))
    return len(write_video(path, frames, scene.fps))


def cell_1080p(tmp: Path) -> Cell:
    """The demo cell with its camera and image zones scaled to 1920x1080."""
    data = read_cell_data(demo_cell_path())
    for cam in data["cameras"]:
        cam["width"], cam["height"] = SIZE
        k = cam["calibration"]["camera_matrix"]
        cam["calibration"]["camera_matrix"] = [[v * SCALE for v in k[0]], [v * SCALE for v in k[1]],
                                               k[2]]
    for zone in data["zones"]:
        if "points_px" in zone:
            zone["points_px"] = [[x * SCALE, y * SCALE] for x, y in zone["points_px"]]
    return parse_cell(data, tmp / "demo-cell-1080p.yaml")


# ``--commissioned``: the camera's commissioning reference (the demo cell empty, at 1080p) and
# the model's envelope, as `monitor run` has them after commissioning: the health stage then
# also checks the image conditions and the objects put into the zones since commissioning
COMMISSIONED: dict = {"reference": None, "envelope": None}


def commissioned(detector: Detector) -> None:
    COMMISSIONED["reference"] = cv2.resize(DemoScene().background(), SIZE,
                                           interpolation=cv2.INTER_LINEAR)
    COMMISSIONED["envelope"] = for_detector(detector, HealthConfig().envelope_min_recall,
                                            store=False)


def new_pipeline(detector: Detector, cell: Cell, pipeline_type: type = Pipeline,
                 config: MonitorConfig | None = None) -> Pipeline:
    config = config or MonitorConfig()
    reference = COMMISSIONED["reference"]
    health = camera_health(config.health, "cam0", reference, cell, COMMISSIONED["envelope"])
    return pipeline_type(detector, "cam0", config.policy, cell, health,
                         references={"cam0": reference})


def pct(values: list[float], q: float) -> float:
    if not values:  # a pass that processed nothing (a host too loaded for the live pass)
        return math.nan
    s = sorted(values)
    return s[min(len(s) - 1, max(0, math.ceil(q * len(s)) - 1))]


def throughput_inline(video: Path, detector: Detector, cell: Cell) -> dict:
    pipeline = new_pipeline(detector, cell)
    whole, bare, stages = [], [], {"read+decode": []}
    persons = 0
    with VideoFileReader(video, "cam0", expected_size=SIZE) as reader:
        for k in itertools.count():
            t0 = time.perf_counter()
            frame = reader.read()
            t1 = time.perf_counter()
            if frame is None:
                break
            if k % 2:  # alternate the order: neither always runs right after the other
                bare.append(_bare(detector, frame.image))
            t2 = time.perf_counter()
            result = pipeline.process(frame.image, frame.info, frame.info.capture_time)
            t3 = time.perf_counter()
            if not k % 2:
                bare.append(_bare(detector, frame.image))
            whole.append((t1 - t0 + t3 - t2) * 1e3)
            stages["read+decode"].append((t1 - t0) * 1e3)
            for s, v in result.stage_ms.items():
                stages.setdefault(s, []).append(v)
            persons += len(result.persons) if result.persons is not None else 0
    return {"whole": whole, "bare": bare, "stages": stages, "persons": persons}


@contextlib.contextmanager
def collections_timed():
    """The garbage collection pauses (ms, any thread) while the block runs, into the list
    yielded."""
    pauses: list[float] = []
    started: list[float] = []

    def timer(phase: str, info: dict) -> None:
        if phase == "start":
            started.append(time.perf_counter())
        elif started:
            pauses.append((time.perf_counter() - started.pop()) * 1e3)
    gc.callbacks.append(timer)
    try:
        yield pauses
    finally:
        gc.callbacks.remove(timer)


class _Replayed:
    """A runner that hands back the outputs the real one gave for each frame, in order (the
    runner seam, monitor/detector/runners.py): a pass through it times only the work around
    inference."""

    def __init__(self, real, outputs: list[list[np.ndarray]]) -> None:
        self.candidate, self.inputs, self.outputs = real.candidate, real.inputs, real.outputs
        self.metadata = real.metadata
        self._queue = iter(outputs)

    def run(self, feeds) -> list[np.ndarray]:
        return next(self._queue)


def fixed_path_cpu(video: Path, detector: Detector, cell: Cell, frames: int = 90) -> dict:
    """The fixed path of the first ``frames`` frames in CPU time, with the model's outputs of
    a first pass replayed instead of running the model (no inference thread runs), which a
    loaded host's waits do not inflate.

    Per frame, the main thread's CPU (``time.thread_time``) of the read and of
    ``Pipeline.process`` with each of its stages, and the CPU of the process's *other*
    threads over the frame (``process_time`` - ``thread_time``): OpenCV's FFmpeg decodes on
    worker threads (frame threading), which go on decoding the next frames while the main
    thread runs the pipeline. Counting the process's CPU from the read to the end of
    ``process`` as one figure (as before 2026-12-02) put that decoding into the pipeline's
    span, so "fixed path in CPU time" (9.8 ms) was far above the stages' wall medians (5.9 ms)
    while "of it read+decode" (the main thread's share, 1.3 ms) was far below the decode's
    real cost. Read+decode is now the read's main-thread CPU plus the worker threads' CPU;
    the pipeline's stages are the main thread's (its only thread with the outputs
    replayed: OpenCV's own pool is counted with the workers, it stays idle here)."""
    with VideoFileReader(video, "cam0", expected_size=SIZE) as reader:
        images = [f.image for f in itertools.islice(reader, frames)]
    recorded = []
    real = detector.runner
    for image in images:  # the model's outputs, each frame's own
        tensor, _ = letterbox(image, detector.layout)
        recorded.append([o.copy() for o in real.run({detector.layout.input_name: tensor})])
    del images
    pipeline = new_pipeline(detector, cell)
    out: dict[str, list[float]] = {"read_main": [], "workers": [], "pipeline": [],
                                   "wall": [], **{s: [] for s in (*CPU_STAGES, *HEALTH_PARTS)}}
    detector.runner = _Replayed(real, recorded)
    stamps = _StageCpu()
    try:
        with VideoFileReader(video, "cam0", expected_size=SIZE) as reader, stamps.timing():
            for _ in range(len(recorded)):
                c0, t0, w0 = time.process_time(), time.thread_time(), time.perf_counter()
                frame = reader.read()
                t1 = time.thread_time()
                stamps.start()
                pipeline.process(frame.image, frame.info, frame.info.capture_time)
                t2, c2 = time.thread_time(), time.process_time()
                out["read_main"].append((t1 - t0) * 1e3)
                out["pipeline"].append((t2 - t1) * 1e3)
                out["workers"].append(((c2 - c0) - (t2 - t0)) * 1e3)
                out["wall"].append((time.perf_counter() - w0) * 1e3)
                for name, ms in stamps.stages().items():
                    out[name].append(ms)
    finally:
        detector.runner = real
    out["read+decode"] = [a + b for a, b in zip(out["read_main"], out["workers"], strict=True)]
    out["cpu"] = [a + b for a, b in zip(out["read+decode"], out["pipeline"], strict=True)]
    return out


class _StageCpu:
    """The main thread's CPU per stage of ``Pipeline.process``, from ``thread_time`` stamps
    taken where the pipeline's own stage timers (``perf_counter``) are taken: the letterbox,
    the runner, the postprocess, the health check and the zones' ``locate`` are wrapped for
    the duration of ``timing()``, and the policy's parts of ``Pipeline._finish`` (the
    confirm-clear, the evidence, the decision, the fault alerts); what is left of ``process``
    is in no stage's timer (``OUTSIDE``: the runner seam and the shape check, building the
    step's result, the screen's views)."""

    def __init__(self) -> None:
        self._ms: dict[str, float] = {}
        self._parts: dict[str, float] = {}
        self._t0 = 0.0

    def start(self) -> None:
        self._ms = dict.fromkeys(CPU_STAGES, 0.0)
        self._parts = dict.fromkeys(HEALTH_PARTS, 0.0)
        self._t0 = time.thread_time()

    def stages(self) -> dict[str, float]:
        """Each stage's CPU, and the health stage's parts (``HEALTH_PARTS``) apart."""
        total = (time.thread_time() - self._t0) * 1e3
        self._ms[OUTSIDE] = max(0.0, total - sum(v for k, v in self._ms.items()
                                                  if k != OUTSIDE))
        return {**self._ms, **self._parts}

    def _wrap(self, owner, name: str, stage: str, part: str = ""):
        inner = getattr(owner, name)

        def timed(*args, **kwargs):
            t = time.thread_time()
            try:
                return inner(*args, **kwargs)
            finally:
                ms = (time.thread_time() - t) * 1e3
                self._ms[stage] = self._ms.get(stage, 0.0) + ms
                if part:
                    self._parts[part] += ms
        setattr(owner, name, timed)
        return inner

    @contextlib.contextmanager
    def timing(self):
        wrapped = [(Letterboxer, "__call__", "preprocess"),
                   (Detector, "postprocess", "decode"),
                   (CameraHealth, "check", "health", HEALTH_PARTS[0]),
                   (ZoneObjects, "check", "health", HEALTH_PARTS[1]),
                   (pipeline_core, "locate", "zones"),
                   *((Pipeline, name, "policy") for name in (
                       "_confirm_clear", "_inputs", "_decide", "_fault_alerts"))]
        saved = [(owner, name, self._wrap(owner, name, *stage))
                 for owner, name, *stage in wrapped]
        try:
            yield
        finally:
            for owner, name, inner in saved:
                setattr(owner, name, inner)


def _bare(detector: Detector, image: np.ndarray) -> float:
    tensor, _ = letterbox(image, detector.layout)  # the same input the pipeline feeds
    feeds = {detector.layout.input_name: tensor}
    t0 = time.perf_counter()
    detector.runner.run(feeds)
    return (time.perf_counter() - t0) * 1e3


def throughput_threaded(video: Path, detector: Detector, cell: Cell) -> dict:
    pipeline = new_pipeline(detector, cell)
    frames: queue.Queue = queue.Queue(maxsize=2)

    def reader_thread() -> None:
        with VideoFileReader(video, "cam0", expected_size=SIZE) as reader:
            for frame in reader:
                frames.put(frame)
        frames.put(None)

    thread = threading.Thread(target=reader_thread, daemon=True)
    thread.start()
    start = time.perf_counter()
    n = 0
    while (frame := frames.get()) is not None:
        pipeline.process(frame.image, frame.info, frame.info.capture_time)
        n += 1
    elapsed = time.perf_counter() - start
    thread.join()
    return {"frames": n, "ms_per_frame": elapsed * 1e3 / n}


def throughput_driver(video: Path, detector: Detector, cell: Cell) -> dict:
    """The replay path: the driver with the video feed (ticks between frames) and a sink."""
    pipeline = new_pipeline(detector, cell)
    summary = ReplaySummary(str(video))
    with VideoFileReader(video, "cam0", expected_size=SIZE) as reader:
        driver = Driver(pipeline, [SummarySink(summary)])
        start = time.perf_counter()
        driver.run(VideoFeed(reader, 0.05, ()), threading.Event())
        elapsed = time.perf_counter() - start
    return {"frames": summary.frames, "ms_per_frame": elapsed * 1e3 / summary.frames,
            "ticks": summary.ticks}


class _TimedPipeline(Pipeline):
    """Remembers the capture stamp of the frame just processed, its inference time, and where
    the time from capture to the decision went (``stages``: queue wait from the capture stamp
    to the start of processing, then the pipeline's own stages)."""

    pending: float | None = None
    inference: list[float]
    stages: dict[str, list[float]]

    def process(self, image, frame, now, **kwargs):
        start = time.monotonic()
        result = super().process(image, frame, now, **kwargs)
        self.pending = frame.capture_time
        self.inference.append(result.stage_ms.get("inference", 0.0))
        self.stages.setdefault("queue wait (capture -> processing)", []).append(
            (start - frame.capture_time) * 1e3)
        for name, ms in result.stage_ms.items():
            self.stages.setdefault(name, []).append(ms)
        self.stages.setdefault("process (all stages)", []).append(
            (time.monotonic() - start) * 1e3)
        return result


class _TimedBus(SafetyBus):
    """Records, per processed frame, when publish_command returned (monotonic)."""

    def __init__(self, config: BusConfig, pipeline: _TimedPipeline) -> None:
        super().__init__(config)
        self.pipeline = pipeline
        self.latency_ms: list[float] = []
        self.capture_of_seq: dict[int, float] = {}

    def publish_command(self, command, decided_at=None):
        t0 = time.monotonic()
        seq = super().publish_command(command, decided_at)
        done = time.monotonic()
        capture, self.pipeline.pending = self.pipeline.pending, None
        if capture is not None:  # a step that processed a frame (not a timer tick)
            self.latency_ms.append((done - capture) * 1e3)
            self.pipeline.stages.setdefault("publish", []).append((done - t0) * 1e3)
            if seq is not None:
                self.capture_of_seq[seq] = capture
        return seq


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def paced_bare(video: Path, detector: Detector, fps: float, frames: int) -> list[float]:
    """``session.run`` alone, once per frame interval (the camera's pace, no other work)."""
    with VideoFileReader(video, "cam0", expected_size=SIZE) as reader:
        frame = reader.read()
    assert frame is not None
    times = []
    for _ in range(frames):
        start = time.perf_counter()
        times.append(_bare(detector, frame.image))
        time.sleep(max(0.0, 1 / fps - (time.perf_counter() - start)))
    return times


def latency(video: Path, detector: Detector, cell: Cell, seconds: float,
            settle: bool = True) -> dict:
    config = MonitorConfig()
    pipeline = new_pipeline(detector, cell, _TimedPipeline, config)
    pipeline.inference, pipeline.stages = [], {}
    pauses: list[float] = []
    gc_start: list[float] = []

    def gc_timer(phase: str, info: dict) -> None:  # every collection's pause, any thread
        if phase == "start":
            gc_start.append(time.perf_counter())
        elif gc_start:
            pauses.append((time.perf_counter() - gc_start.pop()) * 1e3)
    gc.callbacks.append(gc_timer)
    port = free_port()
    bus_cfg = BusConfig(cell="bench", instance="bench", listen=(f"tcp/127.0.0.1:{port}",),
                        config_hash=cell.config_hash)
    received: list[tuple[float, int]] = []
    stop = threading.Event()
    with _TimedBus(bus_cfg, pipeline) as bus, open_session(
            BusConfig(cell="bench", instance="sub", connect=(f"tcp/127.0.0.1:{port}",))) as sub:
        sub.declare_subscriber(bus.keys.command, lambda s: received.append(
            (time.monotonic(), json.loads(s.payload.to_bytes())["seq"])))
        deadline = time.monotonic() + 5
        while not bus._pub_command.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)
        source = PacedSource(VideoFileReader(video, "cam0"), stop=stop)
        source.open()
        grabber = LatestFrameGrabber(source, stop=stop, expected_size=SIZE).start()
        try:
            sink = ServiceSink(bus, Metrics(0, "127.0.0.1"), [grabber])
            feed = LiveFeed([grabber], bus, None, config.service.tick_s, stop,
                            seconds + 0.5, sink.alert)
            if settle:  # as the service does before its loop (that one collection is
                settle_heap()  # start-up, not a pause of the loop)
                pauses.clear()
            # the service's periodic checks too (a self-test every 10 s, the in-place check
            # every 3 s: one more inference each), run where the service runs them
            inplace = inplace_check(detector, cell, ["cam0"], config.health.inplace_period_s)
            Driver(pipeline, [sink], stall_after_s=config.policy.frame_timeout,
                   self_test_period_s=config.detector.self_test_period_s,
                   inplace=inplace).run(feed, stop)
            checks = inplace.runs if inplace is not None else 0
        finally:
            stop.set()
            grabber.stop()
        time.sleep(0.2)  # the last puts arrive
        wire = [(t - bus.capture_of_seq[seq]) * 1e3 for t, seq in received
                if seq in bus.capture_of_seq]
        gc.callbacks.remove(gc_timer)
        return {"latency": bus.latency_ms, "wire": wire, "inference": pipeline.inference,
                "dropped": grabber.dropped, "grabbed": grabber.grabbed,
                "stages": pipeline.stages, "gc": pauses, "inplace_runs": checks}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=12.0,
                        help="video length (the walk enters both zones by 6 s)")
    parser.add_argument("--threads", type=int, default=2, help="inference threads")
    parser.add_argument("--fps", type=float, default=15.0,
                        help="the camera's frame rate (the video is rendered and paced at it)")
    parser.add_argument("--no-settle-heap", action="store_true",
                        help="start the passes without the service's settle_heap (to see "
                        "the garbage collection pauses it saves)")
    parser.add_argument("--int8", action="store_true",
                        help="the synthetic model's int8 file (as `monitor model build --int8`)")
    parser.add_argument("--square", action="store_true",
                        help="every frame in the full 416x416 input ([detector] "
                             "rectangular_input = false), to compare with 416x288")
    parser.add_argument("--backends", default="onnxruntime",
                        help="'all' (every backend and precision here, for the fp32 and the "
                             "int8 model, and what 'auto' chooses), 'auto', or labels such as "
                             "'onnxruntime fp32,openvino bf16,openvino int8': each backend's "
                             "rows side by side")
    parser.add_argument("--commissioned", action="store_true",
                        help="a commissioned camera: its reference (the empty demo cell) and "
                             "the model's envelope, so health also checks the image "
                             "conditions and the objects put into the zones since "
                             "commissioning (without: neither runs)")
    parser.add_argument("--fixed-only", action="store_true",
                        help="only the fixed path in CPU time (outputs replayed, no "
                             "inference): a quick before/after of the work around inference")
    args = parser.parse_args()
    logging.getLogger("monitor").setLevel(logging.ERROR)  # the loop's event lines
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        video = tmp / "demo-1080p.mp4"
        n = make_video(video, args.seconds, args.fps)
        cell = cell_1080p(tmp)
        model = tmp / "tiny-yolov3-synthetic.onnx"  # this version's build, not a cached one
        synthetic.write_model(model)
        int8 = None
        if args.int8 or args.backends == "all" or "int8" in args.backends:
            from monitor.detector import quantize
            from monitor.scene import random_frames

            calib = [f for f, _ in random_frames(8, seed=1000, size=SIZE)]
            int8 = quantize.quantize_model(
                model, tmp / "m.int8.onnx", calib,
                quantize.QuantizeOptions(ranges=synthetic.int8_ranges()))
        config = DetectorConfig(threads=args.threads, rectangular_input=not args.square)
        results = {}
        for label, detector in detectors(args.backends, model, int8 if args.int8 else None,
                                         int8, config):
            print(f"measuring {label} ...", file=sys.stderr, flush=True)
            if args.commissioned:
                commissioned(detector)
            if args.fixed_only:
                report_fixed(fixed_path_cpu(video, detector, cell), label)
                continue
            results[label] = run_passes(video, detector, cell, args, n)
            del detector
            side_by_side({label: results[label]}, args, n, file=sys.stderr)  # as it goes
    if not results:
        return 0
    if len(results) == 1:
        report_one(next(iter(results.values())), args, n)
    else:
        side_by_side(results, args, n)
    return 0


def detectors(which: str, model: Path, only_int8: Path | None, int8: Path | None,
              config: DetectorConfig):
    """(label, Detector) for each backend asked for, one at a time (each freed before the
    next opens). 'auto': what ``monitor run`` would choose here (measured, not cached)."""
    from monitor.detector.choice import open_detector
    from monitor.detector.runners import Candidate, available, model_facts, open_runner

    base = only_int8 or model
    if which == "auto":
        det, choice = open_detector(base, config)
        yield f"auto = {choice.chosen.label}", det
        return
    if which == "all":
        wanted = [(base, c) for c in available(model_facts(base))]
        if int8 is not None and only_int8 is None:
            wanted += [(int8, c) for c in available(model_facts(int8))]
    else:
        wanted = []
        for label in which.split(","):
            cand = Candidate.parse(label.strip().replace(":", " "))
            path = int8 if cand.precision == "int8" and int8 is not None else base
            wanted.append((path, Candidate(cand.backend, cand.precision or "auto")))
    for path, cand in wanted:
        runner = open_runner(path, cand, config.threads, config.spin_wait)
        yield runner.candidate.label, Detector(path, config, runner=runner)
    if which == "all":
        det, choice = open_detector(base, config)
        yield f"auto = {choice.chosen.label}", det


def run_passes(video: Path, detector: Detector, cell: Cell, args, n: int) -> dict:
    # each throughput pass as the service's loop runs: what start-up built frozen out of the
    # collections first. Before 2026-12-02 the first pass paid for collecting what start-up
    # built (the video, the model, the detector): a full and a dozen younger collections,
    # 1-3 ms a frame on the mean the ratio is made of, in no stage's median
    settle = not args.no_settle_heap
    if settle:
        settle_heap()
    with collections_timed() as gc_inline:
        t = throughput_inline(video, detector, cell)
    t["gc"] = gc_inline
    if settle:
        settle_heap()
    th = throughput_threaded(video, detector, cell)
    if settle:
        settle_heap()
    dr = throughput_driver(video, detector, cell)
    lat = latency(video, detector, cell, args.seconds, settle=not args.no_settle_heap)
    paced = paced_bare(video, detector, args.fps, n)
    fixed = fixed_path_cpu(video, detector, cell)
    return {"t": t, "th": th, "dr": dr, "lat": lat, "paced": paced, "fixed": fixed}


FIXED = ("read+decode", "preprocess", "decode", "zones", "health", "policy")
OUTSIDE = "outside every stage's timer"
CPU_STAGES = (*FIXED[1:], OUTSIDE)  # the fixed path's CPU rows
# the health stage's parts: the camera checks (with the envelope and the watch zones) and the
# objects-since-commissioning watch (with ``--commissioned``), on the same analysis image
HEALTH_PARTS = ("health: camera checks", "health: objects watch")


def fixed_ms(stages: dict[str, list[float]]) -> float:
    """The work around inference per frame: the median of each stage but inference, summed."""
    return sum(statistics.median(stages[s]) for s in FIXED if stages.get(s))


def side_by_side(results: dict[str, dict], args, n: int, file=None) -> None:
    """One column per backend: the throughput, stage and latency rows of ``report_one``."""
    def med(values: list[float]) -> float:
        return statistics.median(values) if values else math.nan

    def print(*a, **k) -> None:  # the table to ``file``, stdout by default
        builtins.print(*a, **k, file=file or sys.stdout)

    start_frames = math.ceil(args.fps * MonitorConfig().policy.clear_time)
    rows: dict[str, list[str]] = {}

    def row(name: str, value: str) -> None:
        rows.setdefault(name, []).append(value)

    for r in results.values():
        t, th, dr, lat, paced = r["t"], r["th"], r["dr"], r["lat"], r["paced"]
        bare_ms, whole_ms = sum(t["bare"]) / n, sum(t["whole"]) / n
        running = lat["latency"][start_frames:]
        row("bare inference ms (mean) / fps", f"{bare_ms:.1f} / {1e3 / bare_ms:.1f}")
        row("pipeline, decode inline: ms / fps", f"{whole_ms:.1f} / {1e3 / whole_ms:.1f}")
        ratio = bare_ms / whole_ms
        row("pipeline inline / bare (target >= 0.85)",
            f"{ratio:.3f} ({'met' if ratio >= 0.85 else 'missed'})")
        row("pipeline, decode in a thread / bare", f"{bare_ms / th['ms_per_frame']:.3f}")
        row("replay through the driver / bare", f"{bare_ms / dr['ms_per_frame']:.3f}")
        row("garbage collection in the inline pass: ms a frame (pauses)",
            f"{sum(t['gc']) / n:.2f} ({len(t['gc'])})")
        for stage in ("read+decode", "preprocess", "inference", "decode", "zones", "health",
                      "policy"):
            if stage in t["stages"]:
                row(f"stage {stage} (median ms)", f"{med(t['stages'][stage]):.2f}")
        row("fixed path: every stage but inference (sum of medians, target < 2 ms)",
            f"{fixed_ms(t['stages']):.2f}")
        fx = r["fixed"]
        row("fixed path in CPU time, outputs replayed (median ms)", f"{med(fx['cpu']):.2f}")
        row("... read+decode CPU: main thread + decoder threads",
            f"{med(fx['read+decode']):.2f} = {med(fx['read_main']):.2f} + "
            f"{med(fx['workers']):.2f}")
        row("... pipeline CPU (preprocess, decode, zones, health, policy, outside)",
            f"{med(fx['pipeline']):.2f} = " + " + ".join(f"{med(fx[s]):.2f}"
                                                        for s in CPU_STAGES))
        row("person detections (inline pass)", f"{t['persons']}")
        lt = lat["latency"]
        row("capture -> command median / p99 ms", f"{med(lt):.1f} / {pct(lt, 0.99):.1f}")
        row(f"capture -> command p99 after the first {start_frames} frames",
            f"{pct(running, 0.99):.1f}")
        row("bare inference paced, median / p99 ms", f"{med(paced):.1f} / {pct(paced, 0.99):.1f}")
        share = pct(running, 0.99) - pct(paced, 0.99)
        row("monitor's share of the p99 (after start-up - bare paced; target <= 5 ms)",
            f"{share:.1f} ({'met' if share <= 5 else 'missed'})")
    print(f"1080p video, {n} frames ({args.seconds:g} s, {args.fps:g} fps), model input "
          f"{'416x416' if args.square else '416x288 (rectangular)'}, {args.threads} threads\n")
    print("| | " + " | ".join(results) + " |")
    print("|---|" + "---|" * len(results))
    for name, values in rows.items():
        print(f"| {name} | " + " | ".join(values) + " |")
    first = next(iter(results.values()))
    ref = sum(first["t"]["bare"]) / n
    print("\n| backend | bare inference vs the first column |")
    print("|---|---|")
    for label, r in results.items():
        print(f"| {label} | {ref / (sum(r['t']['bare']) / n):.2f}x |")


def report_fixed(fx: dict, label: str = "") -> None:
    """The fixed path in CPU time (``fixed_path_cpu``), per stage."""
    med = statistics.median
    print(f"\n| fixed path in CPU time{', ' + label if label else ''}, outputs replayed "
          f"({len(fx['cpu'])} frames) | median ms |")
    print("|---|---|")
    print(f"| read+decode: main thread + decoder threads | {med(fx['read+decode']):.2f} "
          f"({med(fx['read_main']):.2f} + {med(fx['workers']):.2f}) |")
    for stage in CPU_STAGES:
        print(f"| {stage} (main thread) | {med(fx[stage]):.2f} |")
        if stage == "health":
            for part in HEALTH_PARTS:
                print(f"| - of it {part.split(': ')[1]} | {med(fx[part]):.2f} |")
    print(f"| pipeline (every stage but inference) | {med(fx['pipeline']):.2f} |")
    print(f"| fixed path in CPU time (per frame) | {med(fx['cpu']):.2f} |")


def report_one(r: dict, args, n: int) -> None:
    med = statistics.median
    t, th, dr, lat, paced = r["t"], r["th"], r["dr"], r["lat"], r["paced"]
    bare_ms, whole_ms = sum(t["bare"]) / n, sum(t["whole"]) / n
    print(f"1080p video, {n} frames ({args.seconds:g} s, {args.fps:g} fps), model input "
          f"{'416x416' if args.square else '416x288 (rectangular)'} "
          f"{'int8' if args.int8 else 'fp32'}, "
          f"{args.threads} threads, {t['persons']} person detections\n")
    print("| throughput | ms per frame (mean) | median ms | fps | / bare inference |")
    print("|---|---|---|---|---|")
    print(f"| bare inference (session.run) | {bare_ms:.1f} | {med(t['bare']):.1f} "
          f"| {1e3 / bare_ms:.1f} | 1.000 |")
    print(f"| pipeline, decode inline (replay) | {whole_ms:.1f} | {med(t['whole']):.1f} "
          f"| {1e3 / whole_ms:.1f} | {bare_ms / whole_ms:.3f} |")
    print(f"| pipeline, decode in a thread (service) | {th['ms_per_frame']:.1f} | - "
          f"| {1e3 / th['ms_per_frame']:.1f} | {bare_ms / th['ms_per_frame']:.3f} |")
    print(f"| replay through the driver (read inline, {dr['ticks']} ticks) "
          f"| {dr['ms_per_frame']:.1f} | - | {1e3 / dr['ms_per_frame']:.1f} "
          f"| {bare_ms / dr['ms_per_frame']:.3f} |")
    print(f"| garbage collection in the inline pass | {sum(t['gc']) / n:.2f} a frame | - "
          f"| {len(t['gc'])} pauses | - |")
    print("\n| stage (inline pass) | median ms |")
    print("|---|---|")
    for stage in ("read+decode", "preprocess", "inference", "decode", "zones", "health",
                  "policy"):
        if stage in t["stages"]:
            print(f"| {stage} | {med(t['stages'][stage]):.2f} |")
    print(f"| fixed path (every stage but inference) | {fixed_ms(t['stages']):.2f} |")
    report_fixed(r["fixed"])
    inf = med(lat["inference"])
    lt, wire = lat["latency"], lat["wire"]
    print(f"\n| latency, live (paced {args.fps:g} fps, real SafetyBus) | n | median ms | p99 ms "
          "| target |")
    print("|---|---|---|---|---|")
    print(f"| inference (session.run inside the pipeline) | {len(lat['inference'])} "
          f"| {inf:.1f} | {pct(lat['inference'], 0.99):.1f} | |")
    print(f"| capture -> publish_command returned | {len(lt)} | {med(lt):.1f} "
          f"| {pct(lt, 0.99):.1f} | median <= {inf + 5:.1f} "
          f"({'met' if med(lt) <= inf + 5 else 'missed'}) |")
    if wire:
        print(f"| capture -> received by a subscriber (changed commands) | {len(wire)} "
              f"| {med(wire):.1f} | {pct(wire, 0.99):.1f} | |")
    print("\n| where capture -> command goes (live pass) | n | p50 ms | p99 ms | p99.9 ms "
          "| max ms |")
    print("|---|---|---|---|---|---|")
    # the monitor starts in STOP and holds it for clear_time of seen-free evidence: the first
    # frames' latency (the start-up self-test and first in-place check run in front of them)
    # cannot delay a STOP of a running robot; the rows after it are the reaction time
    start_frames = math.ceil(args.fps * MonitorConfig().policy.clear_time)
    running = lt[start_frames:]
    for name, values in [*lat["stages"].items(), ("capture -> command", lt),
                         (f"capture -> command after the first {start_frames} frames", running),
                         ("garbage collection pauses", lat["gc"]),
                         (f"bare inference alone, paced at {args.fps:g} fps", paced)]:
        if values:
            print(f"| {name} | {len(values)} | {med(values):.2f} | {pct(values, 0.99):.2f} "
                  f"| {pct(values, 0.999):.2f} | {max(values):.2f} |")
    slowest = sorted(range(len(lt)), key=lambda k: -lt[k])[:4]
    print("\nslowest capture -> command (frame # of the live pass: ms): "
          + ", ".join(f"#{k}: {lt[k]:.1f}" for k in sorted(slowest)))
    ratio, ratio_running = pct(lt, 0.99) / inf, pct(running, 0.99) / inf
    print(f"\ncapture -> command p99 / inference median: {ratio:.2f} (all frames), "
          f"{ratio_running:.2f} after the start-up STOP (target <= 1.5: "
          f"{'met' if ratio_running <= 1.5 else 'missed'})")
    print(f"bare paced inference alone: p99 / median {pct(paced, 0.99) / med(paced):.2f}; "
          f"the monitor's own share of the p99: {pct(running, 0.99) - pct(paced, 0.99):.1f} ms "
          "(capture -> command p99 after start-up - bare paced p99; target <= 5 ms: "
          f"{'met' if pct(running, 0.99) - pct(paced, 0.99) <= 5 else 'missed'})")
    print(f"\nin-place checks in the live pass: {lat['inplace_runs']} (every "
          f"{MonitorConfig().health.inplace_period_s:g} s), self-test every "
          f"{MonitorConfig().detector.self_test_period_s:g} s: each one more inference, run in "
          "a timer tick while no frame waits")
    print(f"\ngrabber: {lat['grabbed']} frames grabbed, {lat['dropped']} dropped (newest wins); "
          f"throughput target >= 0.85: {'met' if bare_ms / whole_ms >= 0.85 else 'missed'} "
          f"inline, {'met' if bare_ms / th['ms_per_frame'] >= 0.85 else 'missed'} threaded")


if __name__ == "__main__":
    sys.exit(main())
