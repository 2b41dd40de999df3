"""int8 benchmark: fp32 against static int8, speed and the quantization choices.

Run: python benchmarks/quantize.py [--repeats N] [--choices] [--frames N]

Speed table: the synthetic model at 416 and 320 in fp32 and int8 (as `monitor model build
--int8` makes it), 1 and 2 threads: median ms of a bare run (onnxruntime) on a letterboxed 1080p
frame (fp32 and int8 in alternating blocks of 10, so both see the same machine load) and the ratio
(target: int8 >= 2x faster at 416 on 2 threads).

--choices: the accuracy of each calibration choice on the synthetic model *without* its
analytic ranges (what a user's model gets): MinMax / Entropy / Percentile, output heads in
float or quantized, 8-bit or 7-bit weights; recall, precision and distractor hits against the
scene's ground truth, and agreement with fp32.
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

from monitor.detector import Candidate, Detector, DetectorConfig, letterbox, open_runner, quantize
from monitor.scene import random_frames
from monitor.scene.accuracy import Accuracy, cell_tolerance_px, score_frame


def speed(tmp: Path, repeats: int) -> None:
    frame = next(f for f, t in random_frames(20, seed=3, size=(1920, 1080)) if t.persons)
    calib = [f for f, _ in random_frames(8, seed=1000, size=(1920, 1080))]
    print("| input | threads | fp32 ms | int8 ms | fp32 / int8 |")
    print("|---|---|---|---|---|")
    for size in (416, 320):
        fp32 = tmp / f"m{size}.onnx"
        synthetic.write_model(fp32, input_size=size)
        int8 = quantize.quantize_model(fp32, tmp / f"m{size}.int8.onnx", calib,
                                       quantize.QuantizeOptions(ranges=synthetic.int8_ranges()))
        tensor, _ = letterbox(frame, Detector(fp32).layout)
        feeds = {"images": tensor.copy()}
        for threads in (1, 2):
            sessions = [open_runner(p, Candidate("onnxruntime", "auto"), threads)
                        for p in (fp32, int8)]
            times: list[list[float]] = [[], []]
            for s in sessions:
                for _ in range(3):
                    s.run(feeds)
            # blocks of 10 runs per model, alternating: both models see the same machine load,
            # and neither runs with the other's weights in the cache (interleaving single runs
            # made the int8 model ~15 % slower here: its weights were evicted each time)
            for _ in range(max(1, repeats // 10)):
                for k, s in enumerate(sessions):
                    s.run(feeds)
                    for _ in range(10):
                        t0 = time.perf_counter()
                        s.run(feeds)
                        times[k].append((time.perf_counter() - t0) * 1e3)
            a, b = statistics.median(times[0]), statistics.median(times[1])
            print(f"| {size} | {threads} | {a:.1f} | {b:.1f} | {a / b:.2f}x |", flush=True)


def choices(tmp: Path, n_frames: int) -> None:
    size = (1280, 720)
    fp32 = tmp / "m.onnx"
    synthetic.write_model(fp32, input_size=320)
    calib = [f for f, _ in random_frames(16, seed=1000, size=size)]
    held = list(random_frames(n_frames, seed=0, size=size))
    ref = Detector(fp32, DetectorConfig(threads=2))
    tol = cell_tolerance_px(size, 320)
    print(f"synthetic model at 320 without analytic ranges; {len(calib)} calibration frames, "
          f"{n_frames} other frames {size[0]}x{size[1]}")
    print("| method | heads | weights | recall | precision | distractor hits | agreement "
          "with fp32 |")
    print("|---|---|---|---|---|---|---|")
    configs = [("minmax", False, True), ("minmax", True, True), ("minmax", False, False),
               ("entropy", False, True), ("percentile", False, True)]
    for method, quantize_heads, seven_bit in configs:
        options = quantize.QuantizeOptions(method=method,
                                           keep_float=() if quantize_heads else None,
                                           reduce_range=seven_bit)
        path = quantize.quantize_model(fp32, tmp / f"{method}.int8.onnx", calib, options)
        det = Detector(path, DetectorConfig(threads=2))
        acc = Accuracy()
        for image, truth in held:
            score_frame(det.detect(image).boxes_px, truth, tol, acc)
        agreement = quantize.compare(ref, det, [f for f, _ in held])
        print(f"| {method} | {'int8' if quantize_heads else 'float'} | "
              f"{'7-bit' if seven_bit else '8-bit'} | {acc.recall:.3f} | {acc.precision:.3f} | "
              f"{acc.distractor_hits} | {agreement.agreement:.3f} |", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--choices", action="store_true", help="accuracy of each choice")
    parser.add_argument("--frames", type=int, default=60, help="frames for --choices")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if args.choices:
            choices(Path(tmp), args.frames)
        else:
            speed(Path(tmp), args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
