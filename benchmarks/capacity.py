"""The start-up capacity check against what the loop then does, per camera, on this machine.

Run: python benchmarks/capacity.py [--seconds S] [--fps F] [--threads T] [--backends all]

``--backends all``: every backend and precision this host has for each model (onnxruntime,
and with the ``[openvino]`` extra OpenVINO fp32 and bf16 for the fp32 model, int8 for the int8
one), each predicted and measured the same way, with a last table of how many cameras at which
fps each serves at p99 <= 100 ms (measured).

For 1, 2 and 4 generated 1080p cameras paced at --fps (their configured ``max_fps``), fp32 and
int8: what ``monitor.service.capacity`` predicts at start (processed fps per camera, worst frame age
at a decision, the verdict at the default limits: frame_timeout 0.5 s, max_frame_age 0.3 s,
stall_timeout 0.5 s), beside what the service's loop measures (``benchmarks/cameras.py``'s
``run_one``, cameras in turn: processed fps, capture-to-command latency). A prediction is good
when the measured fps is at least the predicted one and the measured p99 latency stays under
the predicted latency (the frame age bound adds a whole capture interval to it: the newest
frame waits that long for the next one). The decode time of one frame is printed too: the
constants of ``monitor/service/capacity.py`` come from these figures on a quiet host.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

import cv2  # noqa: E402
from cameras import make_inputs, run_one  # noqa: E402

from monitor.detector import Detector, DetectorConfig, open_runner  # noqa: E402
from monitor.detector.runners import Candidate, available, model_facts  # noqa: E402
from monitor.service.capacity import CameraDemand, Limits, assess, measure_detect_s  # noqa: E402

DEFAULT_LIMITS = Limits(frame_timeout=0.5, max_frame_age=0.3, stall_timeout=0.5,
                        lost_after_s=1.0)


def decode_ms(video: Path, frames: int = 20) -> float:
    """Median time to read and decode one frame of ``video`` (what each camera's grabber
    spends per frame, competing with the detector for the cores)."""
    cap = cv2.VideoCapture(str(video))
    times = []
    try:
        for _ in range(frames):
            t0 = time.perf_counter()
            ok, _image = cap.read()
            if not ok:
                break
            times.append(time.perf_counter() - t0)
    finally:
        cap.release()
    return statistics.median(times) * 1e3


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--backends", default="onnxruntime",
                        help="'all': every backend and precision here; default onnxruntime")
    parser.add_argument("--cameras", default="1,2,4", help="camera counts to run")
    args = parser.parse_args()
    counts = [int(c) for c in args.cameras.split(",")]
    served: dict[str, list[tuple[int, float, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        fp32, int8, videos = make_inputs(Path(tmp), max(counts))
        print(f"1080p cameras paced at {args.fps:g} fps (max_fps), {args.threads} threads, "
              f"{args.seconds:g} s each; decoding one frame: {decode_ms(videos[0]):.1f} ms")
        print("| model | backend | cameras | measured detect ms | predicted fps per camera | "
              "predicted latency / frame age ms | verdict | measured fps per camera | "
              "measured median / p99 latency ms | p99 within predicted latency |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for name, model in (("int8", int8), ("fp32", fp32)):
            cands = (available(model_facts(model)) if args.backends == "all"
                     else [Candidate("onnxruntime", "auto")])
            for cand in cands:
                runner = open_runner(model, cand, args.threads)
                label = runner.candidate.label
                det = Detector(model, DetectorConfig(threads=args.threads), runner=runner)
                detect_s = measure_detect_s(det.detect, [(1920, 1080)], runs=10)
                del det, runner
                for n in counts:
                    demands = [CameraDemand(f"cam{i}", 1920, 1080, args.fps) for i in range(n)]
                    verdict = assess(detect_s, demands, DEFAULT_LIMITS)
                    measured = run_one(model, videos[:n], args.seconds, args.fps, False,
                                       args.threads, cand)
                    ages = max(verdict.frame_age_s.values()) * 1e3
                    fps = min(verdict.processed_fps.values())
                    said = "refused" if verdict.refusal else \
                        ("warns" if verdict.warnings else "ok")
                    latency = verdict.latency_s * 1e3
                    served.setdefault(label, []).append(
                        (n, min(measured["fps"]), measured["p99_ms"]))
                    print(f"| {name} | {label} | {n} | {detect_s * 1e3:.1f} | {fps:.1f} | "
                          f"{latency:.0f} / {ages:.0f} | "
                          f"{said} | {' / '.join(map(str, measured['fps']))} | "
                          f"{measured['median_ms']} / {measured['p99_ms']} | "
                          f"{'yes' if measured['p99_ms'] <= latency else 'NO'} |", flush=True)
    print(f"\n| backend | cameras x fps served at p99 <= 100 ms (measured, {args.fps:g} fps "
          "asked) |")
    print("|---|---|")
    for label, rows in served.items():
        ok = [(n, fps) for n, fps, p99 in rows if p99 <= 100 and fps >= 0.9 * args.fps]
        best = max(ok, default=None)
        print(f"| {label} | {f'{best[0]} x {best[1]:.1f} fps' if best else 'none'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
