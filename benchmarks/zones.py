"""Cost of the per-frame zone and distance checks (``monitor.zones.check_persons``).

Run: /work/venv/bin/python benchmarks/zones.py
Prints a markdown table of median microseconds per frame for 1, 10 and 50 persons against 20
zones: image polygons only, cell volumes only, a 10 + 10 mix, and the mix with the tool
separation (tool pose given). Persons are random boxes over the demo camera's image, about half
of them inside some zone, so the narrow phase (FCL) really runs.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from monitor import geometry as geo
from monitor import zones as zn

WIDTH, HEIGHT = 1280, 720
REPEATS = 400


def calibration() -> dict:
    r, t = geo.look_at((0, -6.0, 3.2), (0, 0, 0.8))
    return {"type": "pinhole", "camera_matrix": [[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]],
            "distortion": [], "rotation": r.tolist(), "translation_m": t.tolist()}


def image_zone(k: int, rng: np.random.Generator) -> dict:
    """A random star-shaped polygon of 6..12 points; every third zone a share anchor."""
    n = int(rng.integers(6, 13))
    centre = rng.uniform([150, 150], [WIDTH - 150, HEIGHT - 150])
    angles = np.sort(rng.uniform(0, 2 * np.pi, n))
    radii = rng.uniform(60, 140, n)
    pts = np.c_[centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles)]
    zone = {"id": f"img{k}", "kind": "warning" if k % 2 else "protective", "shape": "polygon",
            "camera": "cam0", "points_px": np.round(pts, 1).tolist()}
    if k % 2:
        zone["speed_scale"] = 0.3
    if k % 3 == 2:
        zone.update(anchor="share", min_share=0.3)
    return zone


def volume_zone(k: int, rng: np.random.Generator) -> dict:
    """Boxes (some turned), non-convex extruded polygons and cylinders over the floor."""
    x, y = rng.uniform(-3, 3, 2)
    zone: dict = {"id": f"vol{k}", "kind": "warning" if k % 2 else "protective"}
    if k % 2:
        zone["speed_scale"] = 0.3
    if k % 3 == 0:
        zone.update(shape="box", min_m=[x - 0.6, y - 0.4, 0], max_m=[x + 0.6, y + 0.4, 2.0],
                    yaw_deg=float(rng.uniform(0, 90)))
    elif k % 3 == 1:  # an L shape: 6 points, triangulated into convex parts
        zone.update(shape="extrude", points_m=[[x, y], [x + 1.2, y], [x + 1.2, y + 0.4],
                                               [x + 0.4, y + 0.4], [x + 0.4, y + 1.2],
                                               [x, y + 1.2]], z_min_m=0, z_max_m=2.2)
    else:
        zone.update(shape="cylinder", center_m=[x, y], radius_m=0.6, z_min_m=0, z_max_m=2.5)
    return zone


def make_cell(n_image: int, n_volume: int) -> zn.Cell:
    rng = np.random.default_rng(1)
    zones = [image_zone(k, rng) for k in range(n_image)]
    zones += [volume_zone(k, rng) for k in range(n_volume)]
    return zn.parse_cell({
        "version": 1,
        "cameras": [{"id": "cam0", "width": WIDTH, "height": HEIGHT,
                     "calibration": calibration()}],
        "tool": {"shape": "cylinder", "radius_m": 0.05, "length_m": 0.3,
                 "offset": {"translation_mm": [13.55, 1.82, 49.17], "rpy_deg": [0, 0, 180]}},
        "zones": zones,
    })


def person_boxes(n: int, rng: np.random.Generator) -> np.ndarray:
    """Boxes whose feet stand below the horizon (rows 360..715), person-like aspect."""
    h = rng.uniform(120, 320, n)
    x = rng.uniform(40, WIDTH - 40, n)
    y2 = rng.uniform(380, HEIGHT - 5, n)
    w = h * rng.uniform(0.3, 0.45, n)
    return np.c_[x - w / 2, y2 - h, x + w / 2, y2]


def median_us(prep: zn.PreparedCell, boxes: np.ndarray, pose: geo.ToolPose | None) -> float:
    times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        zn.check_persons(prep, "cam0", boxes, tool_pose=pose, tool_speed_mps=0.8)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e6


def main() -> None:
    rng = np.random.default_rng(2)
    pose = geo.ToolPose((0.5, 0.2, 1.1), (0.0, 0.7071068, 0.0, 0.7071068), time=0.0)
    setups = [
        ("20 image polygons", make_cell(20, 0), None),
        ("20 cell volumes", make_cell(0, 20), None),
        ("10 image + 10 volumes", make_cell(10, 10), None),
        ("10 + 10, with tool distance", make_cell(10, 10), pose),
    ]
    counts = (1, 10, 50)
    boxes = {n: person_boxes(n, rng) for n in counts}
    print(f"check_persons per frame, median of {REPEATS} runs (microseconds)\n")
    print("| zones | " + " | ".join(f"{n} person{'s' if n > 1 else ''}" for n in counts)
          + " | hits at 10 |")
    print("|---|" + "---:|" * (len(counts) + 1))
    for label, cell, tool in setups:
        prep = cell.prepared
        cells = [f"{median_us(prep, boxes[n], tool):.0f}" for n in counts]
        hits = len(zn.check_persons(prep, "cam0", boxes[10], tool_pose=tool).hits)
        print(f"| {label} | " + " | ".join(cells) + f" | {hits} |")
    t0 = time.perf_counter()
    zn.prepare_cell(make_cell(10, 10))
    print(f"\nprepare_cell (10 + 10 zones, once at start): "
          f"{(time.perf_counter() - t0) * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
