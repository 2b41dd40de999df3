"""Run every benchmark, one after the other, and print their tables plus each run's peak memory.

Run: python benchmarks/all.py [NAME ...]   (names: detector zones bus health frames pipeline)
Benchmarks measure; they are not tests. Close other work first: the machine has 2 cores.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ORDER = ("detector", "zones", "bus", "health", "frames", "pipeline")


def main(argv: list[str]) -> int:
    names = argv or list(ORDER)
    unknown = [n for n in names if n not in ORDER]
    if unknown:
        print(f"unknown benchmark {unknown[0]!r}; known: {', '.join(ORDER)}", file=sys.stderr)
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
