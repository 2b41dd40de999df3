"""Detector benchmark: median ms per stage on a 1920x1080 frame, and whole detect / bare run.

Run: python benchmarks/detector.py [--repeats N]
For each input size (416, 320, 256) and thread count (1, 2), in one run: preprocess (letterbox
+ tensor), inference (session.run), decode + NMS + merge, the whole detect call, a bare
session.run on the same input tensor, and their ratio (target <= 1.05).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from monitor.models import synthetic

from monitor.detector import Detector, DetectorConfig, letterbox
from monitor.scene import random_frames


def bench(model: Path, threads: int, repeats: int, frame) -> dict[str, float]:
    det = Detector(model, DetectorConfig(threads=threads))
    tensor, _ = letterbox(frame, det.layout)
    feeds = {det.layout.input_name: tensor}
    pre, inf, post, whole, bare = [], [], [], [], []
    for _ in range(3):
        det.detect(frame)
        det.runner.run(feeds)
    for _ in range(repeats):  # interleave so both see the same machine load
        t0 = time.perf_counter()
        r = det.detect_timed(frame)
        whole.append((time.perf_counter() - t0) * 1e3)
        pre.append(r.preprocess_ms)
        inf.append(r.inference_ms)
        post.append(r.decode_ms)
        t0 = time.perf_counter()
        det.runner.run(feeds)
        bare.append((time.perf_counter() - t0) * 1e3)
    med = statistics.median
    return {"pre": med(pre), "inf": med(inf), "post": med(post), "whole": med(whole),
            "bare": med(bare), "ratio": med(whole) / med(bare), "persons": len(r.persons)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=40)
    args = parser.parse_args()
    frame = next(f for f, t in random_frames(20, seed=3, size=(1920, 1080)) if len(t.persons) >= 2)
    print("| input | threads | preprocess ms | inference ms | decode+merge ms | detect ms "
          "| bare run ms | detect / bare | persons |")
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for size in (416, 320, 256):
            model = Path(tmp) / f"m{size}.onnx"
            synthetic.write_model(model, input_size=size)
            for threads in (1, 2):
                r = bench(model, threads, args.repeats, frame)
                print(f"| {size} | {threads} | {r['pre']:.2f} | {r['inf']:.1f} | {r['post']:.2f} "
                      f"| {r['whole']:.1f} | {r['bare']:.1f} | {r['ratio']:.3f} | {r['persons']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
