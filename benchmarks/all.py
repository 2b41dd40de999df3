"""Run every benchmark, one after the other, and print their tables plus each run's peak memory.

Run: python benchmarks/all.py [NAME ...]   (default: every name in ORDER; ``--long`` adds the
long evaluations: mutation testing, 100k-input fuzzing, 20-run shutdown, the scenario set,
the real footage through the real model).
Benchmarks measure; they are not tests. Close other work first: the machine has 2 cores.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ORDER = ("detector", "quantize", "zones", "tracks", "zone_files", "bus", "health", "frames",
         "pipeline", "cameras", "capacity")
LONG = ("mutation", "fuzz", "shutdown", "shutdown_service", "scenarios", "real_footage")


def main(argv: list[str]) -> int:
    long = "--long" in argv
    names = [a for a in argv if a != "--long"] or list(ORDER) + (list(LONG) if long else [])
    unknown = [n for n in names if n not in ORDER + LONG]
    if unknown:
        print(f"unknown benchmark {unknown[0]!r}; known: {', '.join(ORDER + LONG)}",
              file=sys.stderr)
        return 2
    summary = []
    for name in names:
        print(f"\n## {name}\n", flush=True)
        start = time.monotonic()
        proc = subprocess.Popen([sys.executable, str(HERE / f"{name}.py")])
        _, status, usage = os.wait4(proc.pid, 0)  # this child's own peak memory (kB on Linux)
        proc.returncode = os.waitstatus_to_exitcode(status)
        summary.append((name, proc.returncode, time.monotonic() - start, usage.ru_maxrss / 1024))
    print("\n## all\n\n| benchmark | exit | seconds | peak RSS MB |\n|---|---|---|---|")
    for name, code, seconds, peak in summary:
        print(f"| {name} | {code} | {seconds:.0f} | {peak:.0f} |")
    return max((c for _, c, _, _ in summary), default=0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
