"""Cost of the in-place detection check and of the envelope's per-frame image conditions,
against the detector's own inference, on the demo scene (1280x720, cam0, its protective zone).

Run: .venv/bin/python benchmarks/inplace.py [--frames N] [--fps F] [--period S]

The in-place check costs one paste and one inference per protective zone every ``--period``
seconds (default 3 s, the check's default cadence); per frame at ``--fps`` that is its cost
divided by ``fps * period``. Prints a markdown table and the share of inference (the issue's
bound: below 5 % at the default cadence).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from monitor.models import synthetic

from monitor.detector import Detector
from monitor.detector import envelope as env
from monitor.detector.inplace import InPlaceCheck
from monitor.health import CameraHealth, HealthConfig
from monitor.scene import DemoScene
from monitor.zones import load_cell
from monitor.zones.masks import zone_regions_px


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--fps", type=float, default=15.0)
    parser.add_argument("--period", type=float, default=HealthConfig().inplace_period_s)
    args = parser.parse_args()
    from monitor.config import demo_cell_path

    detector = Detector(synthetic.ensure_model())
    envelope = env.for_detector(detector, HealthConfig().envelope_min_recall)
    cell = load_cell(demo_cell_path())
    scene = DemoScene()
    zones = [(z.id, p) for z, p in zone_regions_px(cell, "cam0", ("protective",))]
    frames = [f for f, _ in scene.frames()][::max(1, scene.n_frames // args.frames)]
    frames = frames[:args.frames]
    check = InPlaceCheck(detector.self_test_case, detector.detect, {"cam0": zones},
                         args.period)
    health = CameraHealth(HealthConfig(), "cam0", scene.background(), (), envelope, zones)
    infer, inplace, cond = [], [], []
    for i, frame in enumerate(frames):
        t0 = time.perf_counter()
        detector.detect(frame)
        t1 = time.perf_counter()
        fault = check.check("cam0", frame, float(i))
        t2 = time.perf_counter()
        report = health.check(frame, i / args.fps)
        infer.append((t1 - t0) * 1e3)
        inplace.append((t2 - t1) * 1e3)
        cond.append(report.timings_ms["envelope"])
        if fault is not None:
            print(f"warning: in-place fault on a clean demo frame {i}: {fault.reason}")
    per_frame = np.median(inplace) / (args.fps * args.period)
    rows = [("inference (one frame)", np.array(infer)),
            (f"in-place check ({len(zones)} zone(s), one run)", np.array(inplace)),
            ("image conditions (every frame)", np.array(cond))]
    print("| stage | median ms | p95 ms | max ms |\n|---|---|---|---|")
    for name, v in rows:
        print(f"| {name} | {np.median(v):.2f} | {np.percentile(v, 95):.2f} | {v.max():.2f} |")
    share = per_frame / np.median(infer)
    print(f"\nin-place check per frame at {args.fps:g} fps, every {args.period:g} s: "
          f"{per_frame:.3f} ms = {100 * share:.1f} % of inference (bound 5 %)")
    print(f"image conditions per frame: {100 * np.median(cond) / np.median(infer):.1f} % of "
          "inference")


if __name__ == "__main__":
    main()
