"""The whole test suite, several times in a row, beside a CPU-heavy job: are the tests robust?

A test that passes only on a quiet machine (a sleep that is long enough there, a deadline with
no margin) fails in CI on a busy runner and teaches people to ignore red builds. This script
starts ``--load`` busy processes (each spins one core in pure Python, at normal priority),
runs ``python -m pytest`` ``--runs`` times in a row, and prints a table: run, passed, failed,
errors, wall time, load average. Then, per run, the ten slowest tests (pytest's durations) and
every test that needed more than half of its own wait (a wait's ceiling, tests/helpers.py
``wait_for``): the tests closest to failing under this load. Exit status 1 when any run was not
green, or ended without pytest's summary line (an INTERNALERROR, a crashed scheduler).

    .venv/bin/python benchmarks/suite_under_load.py                 # 3 runs, 1 busy process
    .venv/bin/python benchmarks/suite_under_load.py --runs 1 --load 2 -- -m "not slow"
    .venv/bin/python benchmarks/suite_under_load.py --runs 1 --load 20   # a crushed machine

Slow (three whole suites): a benchmark, never part of the test suite.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import re
import subprocess
import sys
import tempfile
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


def slowest(output: str, n: int = 10) -> list[str]:
    """The first ``n`` lines of pytest's "slowest durations" table ("12.34s call  tests/...")."""
    lines = output.splitlines()
    start = next((i for i, line in enumerate(lines) if "slowest" in line and "durations" in line),
                 None)
    if start is None:
        return []
    rows = [line for line in lines[start + 1:] if re.match(r"\d+\.\d+s ", line)]
    return rows[:n]


def tight_waits(folder: Path) -> list[dict]:
    """The waits the tests noted as taking over half their ceiling, longest first."""
    found = []
    for path in folder.glob("waits-*.jsonl"):
        found += [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return sorted(found, key=lambda w: -w["waited"] / w["ceiling"])


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
            with tempfile.TemporaryDirectory(prefix="waits-") as waits:
                env = {**os.environ, "MONITOR_TEST_WAITS": waits}
                proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p",
                                       "no:cacheprovider", "--durations=10", *args.pytest_args],
                                      cwd=ROOT, capture_output=True, text=True, env=env)
                tight = tight_waits(Path(waits))
            wall = time.monotonic() - t0
            found = counts(proc.stdout)
            # no summary line: pytest itself went down (INTERNALERROR), whatever the counts
            summary = bool(re.search(r"\d+ (passed|failed)", proc.stdout.strip().splitlines()[-1]
                                     if proc.stdout.strip() else ""))
            code = proc.returncode if summary else proc.returncode or 3
            load = os.getloadavg()[0]
            rows.append((run, found, wall, load, code))
            print(f"run {run}: exit {code}, {found}, {wall:.0f} s, load {load:.2f}"
                  + ("" if summary else ", NO SUMMARY (pytest went down)"), flush=True)
            if proc.returncode != 0:
                lines = proc.stdout.splitlines()
                # the names first (pytest's short summary), then the crashes and the first
                # assertion lines
                names = [x for x in lines if x.startswith(("FAILED", "ERROR"))]
                details = [x for x in lines if x.startswith(("E   ", "INTERNALERROR> E"))
                           or "node down" in x or "crashed" in x]
                print("\n".join(names + details[:40]), flush=True)
            print("ten slowest tests:\n  " + "\n  ".join(slowest(proc.stdout) or ["(none)"]),
                  flush=True)
            print(f"tests that needed over half of a wait ({len(tight)}):", flush=True)
            for w in tight:
                print(f"  {w['waited']:.1f} of {w['ceiling']:g} s  {w['test']}: {w['what']}",
                      flush=True)
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
