"""The scenario suite at 10 fps, the clear-view walks behind the zone, and the synthetic
model's box-bottom error that sizes the foot band (monitor/geometry/occlusion.py).

Run: .venv/bin/python benchmarks/scenarios.py [--fps 10] [--skip-error]
Prints two tables: (1) box bottom minus true feet (pixels and grid cells) for persons in clear
view, on the demo scene (1280x720) and on random frames; (2) one row per scenario as
``monitor eval scenarios`` prints it, with the wall time per scenario.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from monitor.models import synthetic

from monitor.detector import Detector
from monitor.replay import scenarios as sc
from monitor.scene import DemoScene, random_frames
from monitor.types import FrameInfo


def box_bottom_errors(detector: Detector) -> list[tuple[str, np.ndarray, float]]:
    """(source, errors px, cell px) for persons in clear view, matched by nearest centre."""
    out = []
    for name, frames, size in (
            ("demo scene 1280x720", DemoScene(fps=3.0).frames(), (1280, 720)),
            ("random frames 1280x720", random_frames(60, seed=3), (1280, 720))):
        errs = []
        for img, truth in frames:
            det = detector.detect_timed(img, FrameInfo("cam0", truth.index, 0.0, *size)).persons
            if not len(det):
                continue
            centres = np.c_[det.boxes_px[:, [0, 2]].mean(axis=1),
                            det.boxes_px[:, [1, 3]].mean(axis=1)]
            for p in truth.persons:
                if p.visible_fraction < 0.99 or p.full_box_px[3] >= size[1] - 5:
                    continue
                c = np.array([(p.box_px[0] + p.box_px[2]) / 2, (p.box_px[1] + p.box_px[3]) / 2])
                k = int(np.argmin(np.linalg.norm(centres - c, axis=1)))
                e = float(det.boxes_px[k, 3]) - p.full_box_px[3]
                if abs(e) < 150:
                    errs.append(e)
        cell = detector.foot_uncertainty_px(*size) / detector.config.foot_uncertainty_cells
        out.append((name, np.array(errs), cell))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fps", type=float, default=10.0)
    ap.add_argument("--skip-error", action="store_true", help="skip the box-bottom table")
    args = ap.parse_args()
    detector = Detector(synthetic.ensure_model())
    if not args.skip_error:
        print("Box bottom minus true feet, persons in clear view (synthetic model)\n")
        print("| frames | persons | min px | median px | p95 px | max px | one cell px | "
              "max cells |")
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
        for name, e, cell in box_bottom_errors(detector):
            print(f"| {name} | {len(e)} | {e.min():.1f} | {np.median(e):.1f} | "
                  f"{np.percentile(e, 95):.1f} | {e.max():.1f} | {cell:.1f} | "
                  f"{e.max() / cell:.2f} |")
        print()
    results, times = [], []
    for s in (*sc.scenarios(args.fps), *sc.behind_scenarios(args.fps)):
        t0 = time.perf_counter()
        results.append(sc.run_scenario(s, detector))
        times.append(time.perf_counter() - t0)
    print(f"Scenarios at {args.fps:g} fps, 640x360, reset request every 0.5 s\n")
    print(sc.format_table(results))
    print("\nwall time per scenario (s): "
          + ", ".join(f"{r.name} {t:.1f}" for r, t in zip(results, times, strict=True)))


if __name__ == "__main__":
    main()
