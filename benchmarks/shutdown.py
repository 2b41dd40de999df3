"""How long `monitor watch`, `router` and `bridge otus` take to end after SIGTERM/SIGINT.

Run: .venv/bin/python benchmarks/shutdown.py [--repeats 20]

For each command and phase (right after start, during start-up / session open at a random
moment, while running), with one signal and with a second one 0.1 s later, under CPU load from
a busy-loop process: the worst and median time from the first signal until the process is
gone. Target: every run under 2 s. The suite (tests/test_shutdown_bus.py) does one run per
case; this does ``--repeats``.
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.test_shutdown_bus import LIMIT_S, cpu_load, stop_time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20, help="runs per case (20)")
    parser.add_argument("--commands", default="watch,router,bridge")
    args = parser.parse_args()
    rng = random.Random(13)
    print(f"{args.repeats} runs per case under CPU load; seconds from the first signal")
    print("| command | phase | signals | median s | max s | over 2 s |")
    print("|---|---|---:|---:|---:|---:|")
    with cpu_load():
        for name in args.commands.split(","):
            for phase in ("running", "start", "opening"):  # running first: time-to-ready
                for second in (False, True):
                    times = [stop_time(name, phase, second, rng)[0]
                             for _ in range(args.repeats)]
                    over = sum(t > LIMIT_S for t in times)
                    print(f"| {name} | {phase} | {2 if second else 1} | "
                          f"{statistics.median(times):.2f} | {max(times):.2f} | {over} |",
                          flush=True)


if __name__ == "__main__":
    main()
