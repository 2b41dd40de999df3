"""Cost of person tracking per frame: tracker update (ByteTrack + holds) and the mask rule.

Run: python benchmarks/tracks.py
Persons walk across the demo camera on the demo cell's floor; the zone report is computed once per
frame outside the timed part (that cost is the zones benchmark's). Prints a markdown table.
"""

from __future__ import annotations

import time

import numpy as np

from monitor.config import demo_cell_path
from monitor.tracking.tracks import PersonTracker
from monitor.types import FrameInfo, Persons
from monitor.zones import check_persons, load_cell
from monitor.zones.masks import MaskRule

W, H = 1280, 720
FRAMES = 300


def boxes_at(n: int, k: int, rng: np.random.Generator) -> np.ndarray:
    """n persons walking in lanes; a little detector jitter; one in ten frames misses one."""
    lane = np.arange(n)
    cx = (100 + 40 * lane + 6 * k) % (W - 100) + 50
    bottom = 380 + 30 * (lane % 10)
    h = 0.5 * bottom
    boxes = np.stack([cx - h / 5, bottom - h, cx + h / 5, bottom], axis=1)
    boxes += rng.normal(0, 2, boxes.shape)
    if k % 10 == 5 and n:
        boxes = boxes[1:]
    return boxes.astype(np.float32)


def bench_tracker(n: int) -> tuple[float, float]:
    cell = load_cell(demo_cell_path())
    rng = np.random.default_rng(0)
    model = cell.camera_models["cam0"]
    tracker = PersonTracker(to_floor=model.pixel_to_floor)
    times = []
    for k in range(FRAMES):
        boxes = boxes_at(n, k, rng)
        persons = Persons(boxes, np.full(len(boxes), 0.9, np.float32),
                          FrameInfo("cam0", k, k / 15, W, H))
        report = check_persons(cell, "cam0", boxes)
        t0 = time.perf_counter()
        tracker.update(persons, report, k / 15, (W, H))
        times.append((time.perf_counter() - t0) * 1e3)
    t = np.array(times[10:])
    return float(np.median(t)), float(np.percentile(t, 99))


def bench_mask(n_boxes: int) -> float:
    cell = load_cell(demo_cell_path())
    rule = MaskRule.for_camera(cell, "cam0", W, H, 49.0)
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, [W - 60, H - 60], (n_boxes, 2))
    boxes = np.concatenate([xy, xy + 55], axis=1)
    t0 = time.perf_counter()
    for _ in range(200):
        rule.keep(boxes)
    return (time.perf_counter() - t0) / 200 * 1e3


def main() -> None:
    print("| what | persons / boxes | median ms | p99 ms |\n|---|---|---|---|")
    for n in (1, 10, 30):
        med, p99 = bench_tracker(n)
        print(f"| tracker update | {n} | {med:.3f} | {p99:.3f} |", flush=True)
    for n in (30, 300):
        print(f"| mask rule (raw boxes) | {n} | {bench_mask(n):.3f} | |", flush=True)


if __name__ == "__main__":
    main()
