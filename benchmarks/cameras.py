"""Four 1080p cameras at 10 fps each on this machine: does the detector keep up?

Run: python benchmarks/cameras.py [--seconds S] [--fps F] [--cameras N]

Four different generated 1080p videos are decoded by one thread per camera, paced at --fps
(a frame is due at t0 + k / fps; it is "captured" at that moment). Each camera holds only its
newest frame: a frame replaced before the monitor took it counts as dropped. The loop is the
service's: every frame that is ready goes through the real ``Pipeline`` - detection as one batch
(``Pipeline.process_batch``, what ``monitor run`` does with ``[detector] batch_cameras``) or one
after the other (``Pipeline.process``), then masks, zone check, person tracker, camera health and
the policy per frame, on the demo cell seen by every camera (its calibration scaled to 1080p).
Latency is from the frame's capture time to its command. Each configuration runs in its own
process so that its peak memory (max RSS) is its own.

Targets: every camera >= 10 fps processed, p99 latency <= 150 ms.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2
import yaml
from monitor.models import synthetic

from monitor.config import demo_cell_path
from monitor.detector import Detector, DetectorConfig, open_runner, quantize
from monitor.health import CameraHealth, HealthConfig
from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig
from monitor.scene import random_frames, write_video
from monitor.types import FrameInfo
from monitor.zones import load_cell


class Mailbox:
    """The newest frame of one camera."""

    def __init__(self) -> None:
        self.item: tuple | None = None
        self.dropped = 0
        self.captured = 0


def capture(path: Path, box: Mailbox, cond: threading.Condition, fps: float, t0: float,
            stop: threading.Event) -> None:
    cap = cv2.VideoCapture(str(path))
    k = 0
    while not stop.is_set():
        due = t0 + k / fps
        delay = due - time.monotonic()
        if delay > 0 and stop.wait(delay):
            break
        ok, image = cap.read()
        if not ok:  # loop the video
            cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, image = cap.read()
        with cond:
            if box.item is not None:
                box.dropped += 1
            box.item = (image, due, k)
            box.captured += 1
            cond.notify()
        k += 1
        if time.monotonic() - due > 1.0:  # far behind: skip ahead like a live camera
            k = int((time.monotonic() - t0) * fps)
    cap.release()


def cell_1080p(tmp: Path, ids: list[str]) -> Path:
    """The demo cell seen by every camera, its calibration and image zones scaled to 1080p."""
    data = yaml.safe_load(demo_cell_path().read_text())
    cam = data["cameras"][0]
    k = 1920 / cam["width"]
    cam.update(width=1920, height=1080)
    matrix = cam["calibration"]["camera_matrix"]
    for r in (0, 1):
        matrix[r] = [v * k for v in matrix[r]]
    data["cameras"] = [dict(cam, id=cid) for cid in ids]
    zones = []
    for zone in data["zones"]:
        if "points_px" in zone:
            zone["points_px"] = [[x * k, y * k] for x, y in zone["points_px"]]
            zones += [dict(zone, camera=cid, id=f"{zone['id']}-{cid}") for cid in ids]
        else:
            zones.append(zone)
    data["zones"] = zones
    path = tmp / "cell-1080p.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def run_one(model: Path, videos: list[Path], seconds: float, fps: float, batch: bool,
            threads: int, candidate=None) -> dict:
    """``candidate``: the backend to run (``monitor.detector.runners.Candidate``); None:
    onnxruntime, the reference."""
    config = DetectorConfig(threads=threads)
    det = Detector(model, config, runner=None if candidate is None
                   else open_runner(model, candidate, threads))
    ids = [f"cam{i}" for i in range(len(videos))]
    cell = load_cell(cell_1080p(videos[0].parent, ids))
    pipe = Pipeline(det, ids, PolicyConfig(), cell,
                    {cid: CameraHealth(HealthConfig(), cid) for cid in ids})
    det.detect_batch([cv2.imread(str(videos[0].with_suffix(".png")))] * len(videos))  # warm up
    boxes = [Mailbox() for _ in videos]
    cond = threading.Condition()
    stop = threading.Event()
    t0 = time.monotonic() + 0.5
    workers = [threading.Thread(target=capture, args=(v, b, cond, fps, t0, stop), daemon=True)
               for v, b in zip(videos, boxes, strict=True)]
    for w in workers:
        w.start()
    latencies: list[float] = []
    processed = [0] * len(videos)
    end = t0 + seconds
    while time.monotonic() < end:
        with cond:
            cond.wait_for(lambda: any(b.item for b in boxes), timeout=0.5)
            ready = [(i, b.item) for i, b in enumerate(boxes) if b.item is not None]
            for b in boxes:
                b.item = None
        if not ready:
            continue
        frames = [(item[0], FrameInfo(ids[i], item[2], item[1], 1920, 1080))
                  for i, item in ready]
        if batch:
            pipe.process_batch(frames, time.monotonic())
            done = [time.monotonic()] * len(frames)
        else:
            done = []
            for image, info in frames:
                pipe.process(image, info, time.monotonic())
                done.append(time.monotonic())
        for (i, item), t in zip(ready, done, strict=True):
            processed[i] += 1
            latencies.append((t - item[1]) * 1e3)
    stop.set()
    for w in workers:
        w.join(timeout=5)
    latencies.sort()
    return {
        "fps": [round(p / seconds, 2) for p in processed],
        "dropped": [b.dropped for b in boxes],
        "median_ms": round(statistics.median(latencies), 1) if latencies else None,
        "p99_ms": round(latencies[int(0.99 * (len(latencies) - 1))], 1) if latencies else None,
        "peak_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 0),
    }


def make_inputs(tmp: Path, cameras: int) -> tuple[Path, Path, list[Path]]:
    fp32 = tmp / "m.onnx"
    synthetic.write_model(fp32)
    calib = [f for f, _ in random_frames(8, seed=1000, size=(1920, 1080))]
    int8 = quantize.quantize_model(fp32, tmp / "m.int8.onnx", calib,
                                   quantize.QuantizeOptions(ranges=synthetic.int8_ranges()))
    videos = []
    for c in range(cameras):
        path = tmp / f"cam{c}.mp4"
        frames = list(random_frames(20, seed=100 + c, size=(1920, 1080)))
        write_video(path, iter(frames), 10.0)
        cv2.imwrite(str(path.with_suffix(".png")), frames[0][0])
        videos.append(path)
    return fp32, int8, videos


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--child", nargs=3, metavar=("MODEL", "BATCH", "VIDEOS"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        model, batch, videos = args.child
        result = run_one(Path(model), [Path(v) for v in videos.split(",")], args.seconds,
                         args.fps, batch == "batch", args.threads)
        print(json.dumps(result))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        fp32, int8, videos = make_inputs(Path(tmp), args.cameras)
        print(f"{args.cameras} cameras 1920x1080 at {args.fps:g} fps, {args.seconds:g} s, "
              f"{args.threads} inference threads")
        print("| model | inference | processed fps per camera | dropped per camera "
              "| latency median ms | p99 ms | peak MB |")
        print("|---|---|---|---|---|---|---|")
        for name, model in (("int8", int8), ("fp32", fp32)):
            for mode in ("batch", "in turn"):
                proc = subprocess.run(
                    [sys.executable, __file__, "--seconds", str(args.seconds), "--fps",
                     str(args.fps), "--threads", str(args.threads), "--child", str(model),
                     "batch" if mode == "batch" else "turn", ",".join(map(str, videos))],
                    capture_output=True, text=True, check=False)
                if proc.returncode != 0:
                    print(f"| {name} | {mode} | failed: {proc.stderr.strip()[-200:]} |")
                    continue
                r = json.loads(proc.stdout.strip().splitlines()[-1])
                print(f"| {name} | {mode} | {' / '.join(map(str, r['fps']))} | "
                      f"{' / '.join(map(str, r['dropped']))} | {r['median_ms']} | "
                      f"{r['p99_ms']} | {r['peak_mb']:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
