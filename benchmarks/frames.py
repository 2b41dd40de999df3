"""Cost of the frame layer: VideoFileReader against bare cv2 decoding, wall and CPU time per
frame, and the grabber hand-off.

Run: /work/venv/bin/python benchmarks/frames.py
Prints a markdown table of medians (and p99 where it matters).
"""

from __future__ import annotations

import statistics
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from monitor.frames import Frame, LatestFrameGrabber, VideoFileReader
from monitor.types import FrameInfo

SIZE = (1920, 1080)
N_FRAMES = 90


def write_video(path: Path) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, SIZE)
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (SIZE[1] // 8, SIZE[0] // 8, 3), np.uint8)
    base = cv2.resize(base, SIZE, interpolation=cv2.INTER_LINEAR)
    for i in range(N_FRAMES):
        writer.write(np.roll(base, 8 * i, axis=1))
    writer.release()


def bare_decode_ms(path: Path) -> tuple[float, float]:
    """(wall, CPU) ms per frame: CPU counts the decoder's threads too (on 2 cores, what
    inference loses)."""
    t0, c0 = time.perf_counter(), time.process_time()  # both include opening the file
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    n = 0
    while cap.read()[0]:
        cap.get(cv2.CAP_PROP_POS_MSEC)
        n += 1
    cap.release()
    return (time.perf_counter() - t0) * 1000 / n, (time.process_time() - c0) * 1000 / n


def reader_ms(path: Path) -> tuple[float, float]:
    t0, c0 = time.perf_counter(), time.process_time()
    with VideoFileReader(path) as reader:
        n = sum(1 for _ in reader)
    return (time.perf_counter() - t0) * 1000 / n, (time.process_time() - c0) * 1000 / n


class TimedSource:
    """A 1080p camera stand-in delivering a frame every ``period_s`` (a sleep, like a driver)."""

    def __init__(self, period_s: float, stop: threading.Event):
        self.camera_id, self.description, self.fps = "bench", "bench source", 1 / period_s
        self.period_s, self.stop = period_s, stop
        self.image = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
        self.is_open = False
        self.seq = 0

    def open(self) -> None:
        self.is_open = True

    def read(self) -> Frame:
        self.stop.wait(self.period_s)
        self.seq += 1
        return Frame(self.image, FrameInfo("bench", self.seq, 0.0, *SIZE))

    def close(self) -> None:
        self.is_open = False


def handoff(period_s: float, consumer_s: float, seconds: float) -> tuple[list[float], float, int]:
    """Latency from grab to get() (ms), frames taken per second, dropped count."""
    stop = threading.Event()
    grabber = LatestFrameGrabber(TimedSource(period_s, stop), stop=stop).start()
    latencies, taken = [], 0
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        frame = grabber.get(timeout=1)
        if frame is None:
            continue
        latencies.append((time.monotonic() - frame.info.capture_time) * 1000)
        taken += 1
        if consumer_s:
            time.sleep(consumer_s)
    dropped = grabber.dropped
    grabber.stop()
    return latencies, taken / seconds, dropped


def p99(values: list[float]) -> float:
    return float(np.percentile(values, 99))


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mp4"
        write_video(path)
        pairs = [(bare_decode_ms(path), reader_ms(path)) for _ in range(7)]  # interleaved: the
        bare = [statistics.median(b[k] for b, _ in pairs) for k in (0, 1)]  # load drifts
        ours = [statistics.median(o[k] for _, o in pairs) for k in (0, 1)]
    fast, fast_fps, fast_drop = handoff(1 / 30, 0.0, 4.0)
    slow, slow_fps, slow_drop = handoff(1 / 30, 0.1, 4.0)
    print(f"| measure (1920x1080, {N_FRAMES} frames mp4v) | median | p99 |")
    print("|---|---|---|")
    print(f"| bare cv2 decode, ms/frame (wall / CPU) | {bare[0]:.2f} / {bare[1]:.2f} | |")
    print(f"| VideoFileReader, ms/frame (wall / CPU) | {ours[0]:.2f} / {ours[1]:.2f} | |")
    print(f"| reader against bare cv2 (wall / CPU) | {ours[0] / bare[0]:.3f}x / "
          f"{ours[1] / bare[1]:.3f}x | |")
    print(f"| grab -> get latency, 30 fps, consumer keeps up, ms | "
          f"{statistics.median(fast):.3f} | {p99(fast):.3f} |")
    print(f"| frames taken/s (consumer keeps up) | {fast_fps:.1f} | dropped {fast_drop} |")
    print(f"| grab -> get latency, 30 fps, consumer 100 ms/frame, ms | "
          f"{statistics.median(slow):.3f} | {p99(slow):.3f} |")
    print(f"| frames taken/s (slow consumer) | {slow_fps:.1f} | dropped {slow_drop} |")


if __name__ == "__main__":
    main()
