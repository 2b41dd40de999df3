"""Zone-file validation time against the number of faults (it must grow linearly).

Run: .venv/bin/python benchmarks/zone_files.py
"""

from __future__ import annotations

import copy
import time
from pathlib import Path

from monitor import zones as zn

DEMO = Path(__file__).resolve().parents[1] / "zones" / "demo-cell.yaml"


def main() -> None:
    data = zn.read_cell_data(DEMO)
    base = data["zones"][0]
    print(f"{'faults':>7}  {'validate_s':>10}  {'us_per_fault':>12}")
    for n in (250, 1000, 4000, 16000):
        d = copy.deepcopy(data)
        d["zones"] = [dict(base, id=f"z{i}", bogus=1) for i in range(n)]
        best = float("inf")
        for _ in range(3):
            start = time.perf_counter()
            errors, _ = zn.cell_faults(d)
            best = min(best, time.perf_counter() - start)
        assert len(errors) == n
        print(f"{n:>7}  {best:>10.3f}  {best / n * 1e6:>12.1f}")


if __name__ == "__main__":
    main()
