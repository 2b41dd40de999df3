"""How fast `monitor run` goes when told, in every phase, repeated (20 times each by default).

Run: .venv/bin/python benchmarks/shutdown_service.py [--reps 20]

Phases (each a fresh `monitor run` subprocess with a looped empty-cell video, the demo zones
and a Zenoh peer on a free tcp/127.0.0.1 port):

- right after start: SIGTERM as soon as the process exists (before the handlers: the default
  action ends it)
- 1.5 s after start: during the imports and the model load
- session open, CPU load: two busy-loop processes; SIGTERM when the "started" line appears
  (the metrics server and the Zenoh session open right after it)
- running: SIGTERM once the first command is logged and the bus port listens
- running, 2nd signal: SIGTERM, then SIGTERM again 50 ms later

Prints one table row per phase: how many runs were gone within 2 s, median and max seconds
from the first signal to the process being gone, and the exit codes seen.
"""

from __future__ import annotations

import argparse
import collections
import signal
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from monitor.models import synthetic

from tests.test_shutdown_service import (
    GONE_WITHIN_S,
    stop_after_start,
    stop_during_session_open,
    stop_while_running,
    write_config,
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=20, help="runs per phase (default: 20)")
    args = parser.parse_args()
    phases = {
        "right after start": lambda c, p, log: stop_after_start(c, p, log, signal.SIGTERM),
        "1.5 s after start (imports, model)": lambda c, p, log: stop_after_start(
            c, p, log, signal.SIGTERM, 1.5),
        "session open, CPU load": lambda c, p, log: stop_during_session_open(
            c, p, log, signal.SIGTERM),
        "running": lambda c, p, log: stop_while_running(c, p, log, signal.SIGTERM)[:2],
        "running, 2nd signal": lambda c, p, log: stop_while_running(
            c, p, log, signal.SIGTERM, second=True)[:2],
    }
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        config, port = write_config(tmp, synthetic.ensure_model())
        print(f"{args.reps} runs per phase; limit {GONE_WITHIN_S} s\n")
        print("| phase | gone within 2 s | median s | max s | exit codes |")
        print("|---|---|---|---|---|")
        for name, run in phases.items():
            times, codes = [], collections.Counter()
            for k in range(args.reps):
                took, code = run(config, port, tmp / f"{k}.log")
                times.append(took)
                codes[code] += 1
            ok = sum(t <= GONE_WITHIN_S for t in times)
            print(f"| {name} | {ok}/{len(times)} | {statistics.median(times):.2f} "
                  f"| {max(times):.2f} | "
                  f"{', '.join(f'{c} x{n}' for c, n in sorted(codes.items()))} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
