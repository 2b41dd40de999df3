"""The whole test suite, several times in a row, beside a CPU-heavy job: are the tests robust?

A test that passes only on a quiet machine (a sleep that is long enough there, a deadline with
no margin) fails in CI on a busy runner and teaches people to ignore red builds. This script
starts ``--load`` busy processes (each spins one core in pure Python, at normal priority),
runs ``python -m pytest`` ``--runs`` times in a row, and prints a table: run, passed, failed,
errors, wall time, load average. Exit status 1 when any run was not green.

    .venv/bin/python benchmarks/suite_under_load.py                 # 3 runs, 1 busy process
    .venv/bin/python benchmarks/suite_under_load.py --runs 1 --load 2 -- -m "not slow"

Slow (three whole suites): a benchmark, never part of the test suite.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def spin(stop: mp.Event) -> None:  # type: ignore[valid-type]
    """Keep one core busy until told to stop (pure Python: holds its own GIL only)."""
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x = (x * 1103515245 + 12345) & 0x7FFFFFFF


def counts(output: str) -> dict[str, int]:
    """passed / failed / errors / skipped from pytest's last summary line."""
    tail = output.strip().splitlines()[-1] if output.strip() else ""
    found = {k: 0 for k in ("passed", "failed", "error", "skipped")}
    for number, word in re.findall(r"(\d+) (passed|failed|errors?|skipped)", tail):
        found["error" if word.startswith("error") else word] += int(number)
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="suites in a row (default 3)")
    parser.add_argument("--load", type=int, default=1,
                        help="busy processes beside the suite (default 1: half of 2 cores)")
    parser.add_argument("pytest_args", nargs="*", help="extra pytest arguments (after --)")
    args = parser.parse_args()

    stop = mp.Event()
    hogs = [mp.Process(target=spin, args=(stop,), daemon=True) for _ in range(args.load)]
    for hog in hogs:
        hog.start()
    rows = []
    try:
        for run in range(1, args.runs + 1):
            t0 = time.monotonic()
            proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                                   *args.pytest_args], cwd=ROOT, capture_output=True, text=True)
            wall = time.monotonic() - t0
            found = counts(proc.stdout)
            load = os.getloadavg()[0]
            rows.append((run, found, wall, load, proc.returncode))
            print(f"run {run}: exit {proc.returncode}, {found}, {wall:.0f} s, load {load:.2f}",
                  flush=True)
            if proc.returncode != 0:
                failing = [line for line in proc.stdout.splitlines()
                           if line.startswith(("FAILED", "ERROR", "E   "))]
                print("\n".join(failing[:40]), flush=True)
    finally:
        stop.set()
        for hog in hogs:
            hog.join(timeout=2)
    print(f"\nwhole suite beside {args.load} busy process(es) on {os.cpu_count()} cores\n")
    print("| run | passed | failed | errors | skipped | wall s | load (1 min) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for run, found, wall, load, _ in rows:
        print(f"| {run} | {found['passed']} | {found['failed']} | {found['error']} | "
              f"{found['skipped']} | {wall:.0f} | {load:.2f} |")
    green = all(code == 0 for *_, code in rows)
    print(f"\n{'all green' if green else 'NOT green'}: {sum(c == 0 for *_, c in rows)} of "
          f"{len(rows)} runs")
    return 0 if green else 1


if __name__ == "__main__":
    sys.exit(main())
