"""Availability and safety of lost persons' holds: the evidence scenes (a stranger stepping out
where a hidden person vanished, a hidden walk, a flickering detector at 1, 2 and 10 fps, two
persons crossing) through the real pipeline, a reset every 0.5 s.

Run: .venv/bin/python benchmarks/availability.py [NAME ...]
Per scene: missed-STOP frames (must be 0), resets accepted with a person inside (must be 0),
resets refused although nobody has been inside the protective zone for clear_time plus a reset
period ("refused free": availability lost), frames with a hold and nobody in the scene, STOP
frames with every person in clear view more than 1 m outside, and the wall time.
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
             "holds when empty", "false STOP", "s")]
    bad = 0
    for scenario in sc.evidence_scenarios():
        if names and scenario.name not in names:
            continue
        t0 = time.perf_counter()
        r = sc.run_scenario(scenario, detector)
        false_stops = sum(s.clear_outside and s.state == "STOP" for s in r.scores)
        bad += r.missed_stop_frames + r.resets_accepted_inside
        rows.append((r.name, str(r.frames), str(r.missed_stop_frames),
                     str(r.resets_accepted_inside), str(r.resets_refused_free),
                     str(r.holds_when_empty), str(false_stops),
                     f"{time.perf_counter() - t0:.1f}"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    for k, row in enumerate(rows):
        print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())
        if k == 0:
            print("  ".join("-" * w for w in widths))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
