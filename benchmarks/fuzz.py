"""Fuzz every outward-facing parser with many inputs and print crashes per target.

Run: .venv/bin/python benchmarks/fuzz.py [--n 100000] [--seed 1] [--targets otus,consumer]

The targets and the mutation engine are those of tests/test_fuzz.py (the suite runs a few
thousand inputs each from a fixed seed); here each target gets ``--n`` inputs from ``--seed``.
A crash is any exception other than the project's one-line errors (``MonitorError``); the
first crash per target is printed with its input and traceback. Expected: 0 crashes.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.test_fuzz import TARGETS, run, stateful


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000, help="inputs per target (100000)")
    parser.add_argument("--seed", type=int, default=1, help="random seed (1)")
    parser.add_argument("--targets", default=",".join(TARGETS),
                        help=f"comma-separated subset of {', '.join(TARGETS)}")
    args = parser.parse_args()
    rows, firsts = [], []
    for name in args.targets.split(","):
        t0 = time.perf_counter()
        res = run(stateful(TARGETS[name]), args.n, args.seed)
        dt = time.perf_counter() - t0
        rows.append((name, res.inputs, res.refused, len(res.crashes), dt))
        if res.crashes:
            firsts.append((name, res.crashes[0]))
        print(f"  {name}: done in {dt:.0f} s", file=sys.stderr, flush=True)
    print("| target | inputs | refused (one-line error) | crashes | s |")
    print("|---|---:|---:|---:|---:|")
    for name, n, refused, crashes, dt in rows:
        print(f"| {name} | {n} | {refused} | {crashes} | {dt:.0f} |")
    for name, (inp, tb) in firsts:
        print(f"\nfirst crash of {name}: input {inp}\n{tb}")


if __name__ == "__main__":
    main()
