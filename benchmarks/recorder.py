"""Incident recorder benchmark: what recording costs the safety loop, and its memory.

Run: .venv/bin/python benchmarks/recorder.py [--cameras 4] [--fps 3] [--block-s 10] [--blocks 4]

1. Latency, in one run: the demo walk (1280x720) as ``--cameras`` live cameras, each paced at
   ``--fps``, through the service's ``Driver`` (stall detection on), with a first sink that
   stands for the safety sink (it stamps when the command would be published). Blocks of
   ``--block-s`` seconds alternate without and with the ``IncidentRecorder`` as the second sink
   (ABAB..., so both see the same machine load); a STOP fault starts every 2 s on one camera,
   so the recorder keeps opening incidents and writing 4-camera clips. Reported: p50/p99 of
   capture -> command per mode and the ratio with/without, incidents, frames dropped.
2. Memory: ``--cameras`` x ``pre_s`` (10 s) x ``max_fps`` (10) frames of 720p pushed through a
   recorder (lossless, so none are dropped): the ring's JPEG bytes, and the process RSS growth.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

from monitor.models import synthetic

from monitor.detector import Detector
from monitor.driver import Driver, Step, StepInputs
from monitor.frames import Frame
from monitor.incidents import RecorderConfig
from monitor.incidents.recorder import IncidentRecorder
from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig
from monitor.scene import DemoScene
from monitor.types import Fault, FrameInfo


class Stamp:
    """The safety sink's place: when the command of each frame step is decided and handed on."""

    def __init__(self) -> None:
        self.recording = False
        self.samples: dict[bool, list[float]] = {False: [], True: []}

    def on_step(self, step: Step) -> None:
        if step.frame is not None:
            self.samples[self.recording].append(time.monotonic() - step.frame.info.capture_time)

    def close(self) -> None:
        pass


class Switch:
    """The recorder as a sink that can be switched off (then it sees nothing at all)."""

    def __init__(self, recorder: IncidentRecorder, stamp: Stamp) -> None:
        self.recorder, self.stamp = recorder, stamp

    def on_step(self, step: Step) -> None:
        if self.stamp.recording:
            self.recorder.on_step(step)

    def close(self) -> None:
        self.recorder.close()


class PacedFeed:
    """Each camera's frames at ``fps`` on the monotonic clock, captured "now"; a new STOP
    fault on cam0 every ``fault_every_s`` (each with its own name: a new incident)."""

    def __init__(self, images, cameras: list[str], fps: float, seconds: float,
                 fault_every_s: float = 2.0) -> None:
        self.images, self.cameras, self.period = images, cameras, 1.0 / (fps * len(cameras))
        self.start = time.monotonic()
        self.end = self.start + seconds
        self.k = 0
        self.fault_every_s = fault_every_s

    def next(self, idle: bool = False):  # frames at their pace: no ticks for checks
        due = self.start + self.k * self.period
        now = time.monotonic()
        if now >= self.end:
            return None
        if due > now:
            time.sleep(due - now)
        cam = self.cameras[self.k % len(self.cameras)]
        seq = self.k // len(self.cameras)
        image = self.images[seq % len(self.images)]
        self.k += 1
        t = time.monotonic()
        return Frame(image, FrameInfo(cam, seq, t, image.shape[1], image.shape[0])), t

    def inputs(self, now: float) -> StepInputs:
        n = int((now - self.start) / self.fault_every_s)
        fault = Fault(f"bench_fault_{n}", "benchmark", True, "cam0")
        return StepInputs(extra_faults=(fault,) if n % 2 else ())


def pct(values: list[float], q: float) -> float:
    return statistics.quantiles(values, n=100)[q - 1] * 1000 if len(values) > 2 else float("nan")


def latency(args, images, detector, data_dir: Path) -> dict:
    cameras = [f"cam{k}" for k in range(args.cameras)]
    pipeline = Pipeline(detector, cameras, PolicyConfig(), None, None)
    stamp = Stamp()
    recorder = IncidentRecorder(RecorderConfig(enabled=True), data_dir, cameras)
    driver = Driver(pipeline, [stamp, Switch(recorder, stamp)], stall_after_s=5.0)
    stop = threading.Event()
    for block in range(args.blocks):
        stamp.recording = block % 2 == 1
        driver.run(PacedFeed(images, cameras, args.fps, args.block_s), stop)
    driver.close()
    off, on = stamp.samples[False], stamp.samples[True]
    return {"off_p50": pct(off, 50), "off_p99": pct(off, 99), "on_p50": pct(on, 50),
            "on_p99": pct(on, 99), "n_off": len(off), "n_on": len(on),
            "status": recorder.status()}


def memory(args, images, data_dir: Path) -> dict:
    cameras = [f"cam{k}" for k in range(args.cameras)]
    config = RecorderConfig(enabled=True)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    recorder = IncidentRecorder(config, data_dir, cameras, lossless=True)
    from monitor.pipeline import StepResult
    from monitor.policy import Command

    command = Command("RUN", 1.0)
    n = int(config.pre_s * config.max_fps)
    for seq in range(n):
        for cam in cameras:
            image = images[seq % len(images)]
            info = FrameInfo(cam, seq, seq / config.max_fps, image.shape[1], image.shape[0])
            recorder.on_step(Step(StepResult(info.capture_time, command, False, frame=info),
                                  Frame(image, info), seq))
    while recorder.status()["queued"]:
        time.sleep(0.05)
    status = recorder.status()
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    recorder.close()
    return {"frames": status["ring_frames"], "ring_mb": status["ring_bytes"] / 2 ** 20,
            "budget_mb": config.memory_mb, "rss_growth_mb": (rss1 - rss0) / 1024}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--fps", type=float, default=3.0, help="frames a second per camera")
    parser.add_argument("--block-s", type=float, default=10.0)
    parser.add_argument("--blocks", type=int, default=4)
    args = parser.parse_args()
    scene = DemoScene(fps=5.0, duration_s=4.0)
    images = [image for image, _ in scene.frames()]
    detector = Detector(synthetic.ensure_model())
    with tempfile.TemporaryDirectory() as tmp:
        mem = memory(args, images, Path(tmp) / "memory")
        lat = latency(args, images, detector, Path(tmp) / "latency")
    s = lat["status"]
    print(f"{args.cameras} cameras x {args.fps:g} fps of 1280x720, blocks of {args.block_s:g} s "
          f"alternating without/with the recorder ({args.blocks} blocks)")
    print("| capture -> command | p50 ms | p99 ms | frames |")
    print("|---|---|---|---|")
    print(f"| without recorder | {lat['off_p50']:.1f} | {lat['off_p99']:.1f} | {lat['n_off']} |")
    print(f"| with recorder | {lat['on_p50']:.1f} | {lat['on_p99']:.1f} | {lat['n_on']} |")
    print(f"p99 ratio with/without: {lat['on_p99'] / lat['off_p99']:.2f}; "
          f"p50 ratio: {lat['on_p50'] / lat['off_p50']:.2f}")
    print(f"recorder: {s['incidents']} incidents, {s['dropped_frames']} frames dropped, "
          f"stopped: {s['stopped']}")
    print(f"memory, {args.cameras} cameras x 10 s x 10 fps of 720p: {mem['frames']} frames in "
          f"the ring, {mem['ring_mb']:.1f} MB of JPEG (budget {mem['budget_mb']:g} MB); process "
          f"RSS grew {mem['rss_growth_mb']:.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
