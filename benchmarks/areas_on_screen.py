"""What the lost persons' areas on screen cost (issue 46): the evidence and busy scenes through
the real pipeline (synthetic model), and per frame the time of the step's area copies
(``holds.area_views`` + ``unseen_views``: every step builds them), of the console's share of
the detections message (``areas_body``: outlines, per published frame) and its size, and of
drawing them on the annotated frame (``areas_draw``: fill, outline, label, hatching).

Run: .venv/bin/python benchmarks/areas_on_screen.py [NAME ...]
Prints one row per scene: frames, frames with an area, the largest number of areas at once,
median and worst ms of each part, and the median/worst message bytes.
"""

from __future__ import annotations

import json
import statistics
import sys
import time

import numpy as np
from monitor.models import synthetic

from monitor.detector import Detector
from monitor.pipeline import Pipeline
from monitor.pipeline.area_views import areas_body
from monitor.pipeline.holds import area_views, unseen_views
from monitor.policy import PolicyConfig
from monitor.records.areas_draw import draw_areas, draw_unseen
from monitor.replay import scenarios as sc
from monitor.types import FrameInfo
from monitor.zones import parse_cell

DEFAULT = ("stranger-2fps", "hidden-walk-10fps", "flicker-10fps", "busy-flicker-5fps",
           "busy-polygons-5fps")


def _ms(values: list[float]) -> str:
    return f"{statistics.median(values):.3f} / {max(values):.3f}" if values else "-"


def main(names: list[str]) -> int:
    detector = Detector(synthetic.ensure_model())
    rows = [("scene", "frames", "with area", "most areas", "views ms (med/max)",
             "body ms", "draw ms", "body bytes (med/max)")]
    wanted = set(names or DEFAULT)
    for scenario in [*sc.evidence_scenarios(), *sc.busy_scenarios()]:
        if scenario.name not in wanted:
            continue
        cell = parse_cell(scenario.zone_data())
        cam = scenario.scene.camera
        pipe = Pipeline(detector, cam.camera_id, PolicyConfig(), cell)
        views, bodies, draws, sizes = [], [], [], []
        frames = with_area = most = 0
        for k, (img, truth) in enumerate(scenario.scene.frames()):
            t = truth.time_s
            res = pipe.process(img, FrameInfo(cam.camera_id, k, t, cam.width, cam.height), t)
            frames += 1
            t0 = time.perf_counter()
            areas = area_views(pipe.cameras, pipe.persons, cell)
            unseen = unseen_views(pipe.cameras)
            views.append((time.perf_counter() - t0) * 1e3)
            t0 = time.perf_counter()
            body = areas_body(areas, unseen, cam.camera_id)
            bodies.append((time.perf_counter() - t0) * 1e3)
            sizes.append(len(json.dumps(body)))
            out = np.ascontiguousarray(img.copy())
            t0 = time.perf_counter()
            draw_unseen(out, unseen, cam.camera_id)
            draw_areas(out, areas, cam.camera_id)
            draws.append((time.perf_counter() - t0) * 1e3)
            with_area += bool(res.areas)
            most = max(most, len(res.areas))
        rows.append((scenario.name, frames, with_area, most, _ms(views), _ms(bodies),
                     _ms(draws), f"{int(statistics.median(sizes))} / {max(sizes)}"))
    widths = [max(len(str(r[i])) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        print("  ".join(str(v).ljust(w) for v, w in zip(r, widths, strict=True)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
