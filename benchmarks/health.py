"""Cost of the camera health checks per 1080p frame (median over the demo scene, upscaled).

Run: /work/venv/bin/python benchmarks/health.py [--frames N]

Prints a markdown table: median, mean, 95th percentile and max of each check and of all
together, in milliseconds, with the moved check (phase correlation) at its default interval,
and the median with it on every frame. Frames are the demo scene (a person walks, the robot
moves) resized to 1920x1080, with the demo shelf as a watch zone and the static background as
the reference.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from monitor.health import CHECKS, CameraHealth, HealthConfig
from monitor.scene import DemoScene

SIZE = (1920, 1080)
SHELF_PX = np.array([[1000, 120], [1200, 120], [1200, 300], [1000, 300]], float)  # at 1280x720


def run(frames: list[tuple[np.ndarray, np.ndarray]], reference: np.ndarray,
        config: HealthConfig, fps: float) -> dict[str, np.ndarray]:
    scale = SIZE[0] / 1280
    health = CameraHealth(config, "cam0", reference, [("shelf", SHELF_PX * scale)])
    rows: dict[str, list[float]] = {name: [] for name in (*CHECKS, "total")}
    moved_runs: list[float] = []
    for i, (image, boxes) in enumerate(frames * 3):  # 3 passes: warm caches, longer sample
        report = health.check(image, i / fps, boxes)
        for name in rows:
            rows[name].append(report.timings_ms[name])
        if "shift_px" in report.measures:
            moved_runs.append(report.timings_ms["moved"])
    out = {name: np.array(values) for name, values in rows.items()}
    out["moved (when it runs)"] = np.array(moved_runs)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=150, help="demo frames (default 150)")
    args = parser.parse_args()
    scene = DemoScene(duration_s=args.frames / 15.0)
    scale = SIZE[0] / 1280
    frames = []
    for image, truth in scene.frames():
        boxes = np.array([p.box_px for p in truth.persons], np.float32).reshape(-1, 4) * scale
        frames.append((cv2.resize(image, SIZE, interpolation=cv2.INTER_LINEAR), boxes))
    reference = cv2.resize(scene.background(), SIZE, interpolation=cv2.INTER_LINEAR)
    time.sleep(0.1)
    print(f"Health checks per {SIZE[0]}x{SIZE[1]} frame, ms ({len(frames) * 3} frames, "
          f"cv2 threads {cv2.getNumThreads()})\n")
    print("| check | median | mean | p95 | max | median, moved every frame |")
    print("|---|---|---|---|---|---|")
    default = run(frames, reference, HealthConfig(), scene.fps)
    every = run(frames, reference, HealthConfig(moved_interval_s=0.0), scene.fps)
    for name in (*CHECKS, "moved (when it runs)", "total"):
        values = default[name]
        print(f"| {name} | {np.median(values):.3f} | {values.mean():.3f} | "
              f"{np.percentile(values, 95):.3f} | "
              f"{values.max():.3f} | {np.median(every[name]):.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
