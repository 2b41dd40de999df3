"""Availability and safety of lost persons' holds: the evidence scenes (a stranger stepping out
where a hidden person vanished, a hidden walk, a flickering detector at 1, 2 and 10 fps, two
persons crossing) and the busy scenes (a real detector on a busy cell, also with image-polygon
zones on an uncalibrated camera, as real footage is set up) through the real pipeline, a reset
every 0.5 s.

Run: .venv/bin/python benchmarks/availability.py [NAME ...]
Per scene: missed-STOP frames (must be 0), resets accepted with a person inside (must be 0),
resets refused (while latched) although nobody has been inside the protective zone for
clear_time plus a reset period ("refused free": availability lost), frames with a hold and
nobody in the scene, holds alive after the last frame, the longest any hold lived after its
person was lost, STOP frames with every person in clear view more than 1 m outside, and the
wall time; a last row sums the columns.
"""

from __future__ import annotations

import sys
import time

from monitor.models import synthetic

from monitor.detector import Detector
from monitor.replay import scenarios as sc


def main(names: list[str]) -> int:
    detector = Detector(synthetic.ensure_model())
    rows = [("scene", "frames", "missed STOP", "accepted inside", "refused free",
             "holds when empty", "holds at end", "oldest hold s", "false STOP", "s")]
    bad = 0
    total = [0] * 6
    for scenario in [*sc.evidence_scenarios(), *sc.busy_scenarios()]:
        if names and scenario.name not in names:
            continue
        t0 = time.perf_counter()
        r = sc.run_scenario(scenario, detector)
        false_stops = sum(s.clear_outside and s.state == "STOP" for s in r.scores)
        bad += r.missed_stop_frames + r.resets_accepted_inside
        counts = (r.frames, r.missed_stop_frames, r.resets_accepted_inside,
                  r.resets_refused_free, r.holds_when_empty, r.holds_at_end)
        total = [a + b for a, b in zip(total, counts, strict=True)]
        rows.append((r.name, *map(str, counts), f"{r.oldest_hold_s:.1f}", str(false_stops),
                     f"{time.perf_counter() - t0:.1f}"))
    rows.append(("total", *map(str, total), "", "", ""))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    for k, row in enumerate(rows):
        print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())
        if k == 0:
            print("  ".join("-" * w for w in widths))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
