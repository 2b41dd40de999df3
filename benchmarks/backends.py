"""Bare inference per backend and precision, and what ``[detector] backend = "auto"`` chooses.

Run: .venv/bin/python benchmarks/backends.py [--threads 2] [--blocks 6]

The synthetic model (fp32) and its int8 build, every backend and precision this host has
(monitor/detector/runners.py: onnxruntime; with the ``[openvino]`` extra OpenVINO fp32, bf16 and
int8), a bare ``runner.run`` on a letterboxed 1080p frame (the 416x288 input a 16:9 camera runs
at), in alternating blocks of 10 runs (every backend sees the same machine load, and none runs
with another's weights in the cache). Then ``monitor.detector.choice.open_detector`` as ``monitor
run`` calls it (measured afresh, not cached): the backend it chooses, its agreement, and the
choice's own time. The host's CPU and flags come first: bf16 on OpenVINO needs AVX-512 BF16 or
AMX, int8 gains need VNNI.
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

from monitor.detector import DetectorConfig, letterbox, quantize
from monitor.detector.choice import cache_path, host_key, host_text, open_detector
from monitor.detector.runners import available, model_facts, open_runner
from monitor.scene import DemoScene, random_frames


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--blocks", type=int, default=6, help="blocks of 10 runs per backend")
    args = parser.parse_args()
    import cv2

    frame = cv2.resize(next(iter(DemoScene().frames()))[0], (1920, 1080))
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        fp32 = tmp / "m.onnx"
        synthetic.write_model(fp32)
        calib = [f for f, _ in random_frames(8, seed=1000, size=(1920, 1080))]
        int8 = quantize.quantize_model(fp32, tmp / "m.int8.onnx", calib,
                                       quantize.QuantizeOptions(ranges=synthetic.int8_ranges()))
        config = DetectorConfig(threads=args.threads)
        from monitor.detector import Detector

        layout = Detector(fp32, config).layout
        tensor, _ = letterbox(frame, layout)
        feeds = {layout.input_name: tensor.copy()}
        runners = [(path, open_runner(path, cand, args.threads))
                   for path in (fp32, int8) for cand in available(model_facts(path))]
        for _, r in runners:
            for _ in range(3):
                r.run(feeds)
        times: list[list[float]] = [[] for _ in runners]
        for _ in range(args.blocks):
            for k, (_, r) in enumerate(runners):
                r.run(feeds)
                for _ in range(10):
                    t0 = time.perf_counter()
                    r.run(feeds)
                    times[k].append((time.perf_counter() - t0) * 1e3)
        print(f"host: {host_text(host_key())}; {args.threads} threads, input "
              f"{tensor.shape[3]}x{tensor.shape[2]}, {args.blocks} x 10 runs each\n")
        print("| model | backend | median ms | p90 ms | vs onnxruntime fp32 |")
        print("|---|---|---|---|---|")
        ref = statistics.median(times[0])
        for (path, r), t in zip(runners, times, strict=True):
            med = statistics.median(t)
            p90 = sorted(t)[int(0.9 * len(t)) - 1]
            print(f"| {'int8' if path == int8 else 'fp32'} | {r.candidate.label} | {med:.1f} "
                  f"| {p90:.1f} | {med / ref:.2f} |")
        del runners
        for path in (fp32, int8):
            cache_path(path).unlink(missing_ok=True)
            t0 = time.perf_counter()
            _, choice = open_detector(path, config)
            took = time.perf_counter() - t0
            print(f"\nauto on the {'int8' if path == int8 else 'fp32'} model ({took:.1f} s to "
                  f"choose, then cached): {choice.line()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
