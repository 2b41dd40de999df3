"""The live preview's cost to the safety loop: capture -> command latency without a preview,
and with the preview publishing and a viewer receiving it (docs/console.md "The live picture").

Run: .venv/bin/python benchmarks/preview.py [--rounds 4] [--seconds 10] [--fps 1]

The live loop of `monitor run` (``LatestFrameGrabber`` -> ``Driver`` + ``LiveFeed`` +
``ServiceSink`` with a real signed ``SafetyBus`` on tcp/127.0.0.1) on the 1080p demo walk paced
at 15 fps (benchmarks/pipeline.py's video and cell). Latency = the moment the service's sink
returned from publishing the step's command - the frame's capture stamp (a sink right after
it takes the time). Two modes, alternated round by round so both see the same machine load:

- off: no preview sink (``[preview] fps = 0``);
- viewer: the preview sink (``monitor.bus.preview.start_preview``, last of the sinks as in the
  service) and a viewer session in this process that verifies and decodes every picture, as the
  console does (in-process: its CPU and the GIL compete with the loop, a harsher case than a
  console in its own process).

Prints p50/p99 per mode over all rounds, per round, and the pictures received. Target: the
viewer's p99 within 5 % of off's.
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from monitor.models import synthetic
from pipeline import SIZE, cell_1080p, free_port, make_video, pct

from monitor.bus.preview import PreviewConfig, read_preview, start_preview
from monitor.bus.session import BusConfig, SafetyBus, open_session
from monitor.config import MonitorConfig
from monitor.detector import Detector, DetectorConfig
from monitor.driver import Driver
from monitor.frames import LatestFrameGrabber, PacedSource, VideoFileReader
from monitor.health import CameraHealth
from monitor.pipeline import Pipeline
from monitor.service.loop import LiveFeed, ServiceSink
from monitor.service.metrics import Metrics
from monitor.wire.signing import load_public_key, new_key_pair
from monitor.zones import watch_regions


class Timing:
    """A sink right after the service's: the time from capture to the command published."""

    def __init__(self) -> None:
        self.ms: list[float] = []

    def on_step(self, step) -> None:
        if step.frame is not None:
            self.ms.append((time.monotonic() - step.frame.info.capture_time) * 1e3)

    def close(self) -> None:
        pass


def one_phase(video: Path, detector: Detector, cell, bus: SafetyBus, seconds: float,
              preview: PreviewConfig | None) -> list[float]:
    config = MonitorConfig()
    health = CameraHealth(config.health, "cam0", None, watch_regions(cell, "cam0"))
    pipeline = Pipeline(detector, "cam0", config.policy, cell, health)
    stop = threading.Event()
    source = PacedSource(VideoFileReader(video, "cam0"), stop=stop)
    source.open()
    grabber = LatestFrameGrabber(source, stop=stop, expected_size=SIZE).start()
    timing = Timing()
    started = start_preview(preview, bus, lambda *a, **k: None) if preview else None
    try:
        sink = ServiceSink(bus, Metrics(0, "127.0.0.1"), [grabber])
        sinks = [sink, timing] + ([started[0]] if started else [])
        feed = LiveFeed([grabber], bus, None, config.service.tick_s, stop, seconds,
                        sink.alert)
        Driver(pipeline, sinks, stall_after_s=config.policy.frame_timeout).run(feed, stop)
    finally:
        stop.set()
        grabber.stop()
        if started:
            started[1]()
    return timing.ms[15:]  # the first second warms the model's caches


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=4, help="rounds of (off, viewer)")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds per phase")
    parser.add_argument("--fps", type=float, default=1.0, help="[preview] fps")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    args = parser.parse_args()
    logging.getLogger("monitor").setLevel(logging.ERROR)
    results: dict[str, list[list[float]]] = {"off": [], "viewer": []}
    received = {"pictures": 0, "refused": 0}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        video = tmp / "demo-1080p.mp4"
        make_video(video, args.seconds + 1)
        cell = cell_1080p(tmp)
        detector = Detector(synthetic.ensure_model(), DetectorConfig(threads=args.threads))
        private, public, _ = new_key_pair(tmp / "monitor.key")
        key = load_public_key(public)
        port = free_port()
        bus_cfg = BusConfig(cell="bench", instance="bench", listen=(f"tcp/127.0.0.1:{port}",),
                            config_hash=cell.config_hash, signing_key=str(private))
        with SafetyBus(bus_cfg) as bus, open_session(BusConfig(
                cell="bench", instance="viewer", connect=(f"tcp/127.0.0.1:{port}",))) as view:

            def on_picture(sample) -> None:  # what the console does with each picture
                payload = sample.payload.to_bytes()
                sig = sample.attachment.to_bytes() if sample.attachment else None
                got = read_preview(payload, sig, bus.keys.preview, (key,), True)
                if got is None:
                    received["refused"] += 1
                    return
                cv2.imdecode(np.frombuffer(got.jpeg, np.uint8), cv2.IMREAD_COLOR)
                received["pictures"] += 1

            sub = view.declare_subscriber(bus.keys.preview, on_picture)
            view.declare_subscriber(bus.keys.command, lambda s: None)
            for r in range(args.rounds):
                order = ("off", "viewer") if r % 2 == 0 else ("viewer", "off")
                for mode in order:
                    cfg = PreviewConfig(fps=args.fps) if mode == "viewer" else None
                    results[mode].append(one_phase(video, detector, cell, bus, args.seconds,
                                                   cfg))
            sub.undeclare()
    med = statistics.median
    print(f"1080p demo walk paced at 15 fps, {args.rounds} rounds x {args.seconds:g} s per "
          f"mode, preview {args.fps:g} fps at most 640 px wide, signed; model threads "
          f"{args.threads}\n")
    print("| mode | frames | capture->command p50 ms | p99 ms | max ms |")
    print("|---|---|---|---|---|")
    every = {m: [v for run in runs for v in run] for m, runs in results.items()}
    for mode, values in every.items():
        print(f"| {mode} | {len(values)} | {med(values):.1f} | {pct(values, 0.99):.1f} "
              f"| {max(values):.1f} |")
    print("\n| round | off p99 | viewer p99 |")
    print("|---|---|---|")
    for r, (a, b) in enumerate(zip(results["off"], results["viewer"], strict=True)):
        print(f"| {r + 1} | {pct(a, 0.99):.1f} | {pct(b, 0.99):.1f} |")
    ratio = pct(every["viewer"], 0.99) / pct(every["off"], 0.99)
    print(f"\npictures received and decoded by the viewer: {received['pictures']} "
          f"(refused: {received['refused']}); viewer p99 / off p99 = {ratio:.3f} "
          f"(target <= 1.05: {'met' if ratio <= 1.05 else 'missed'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
