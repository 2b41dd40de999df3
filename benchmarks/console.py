"""One console viewer's effect on the safety loop (docs/console.md).

Run: .venv/bin/python benchmarks/console.py [--seconds 15]

A real `monitor run` (the looped empty-cell video, the demo zones, the synthetic model, a Zenoh
peer on a free tcp/127.0.0.1 port) and a peer in this process that times every command and
detections message. Three phases of --seconds each:

- baseline: no console;
- one viewer: `monitor console` following the monitor, and one viewer fetching what the live
  page fetches (the state every 0.3 s, the drawn camera image every 0.7 s);
- console killed: the console is SIGKILLed at the start of the phase (the monitor must go on
  commanding as before).

Prints per phase: frames per second decided (detections messages), command gaps (median, 99th
percentile, max, ms), commands received, and the console's CPU use. No benchmarks/recorder.py
exists yet; when it does, run both on the same host and add the recorder as a fourth phase.
"""

from __future__ import annotations

import argparse
import itertools
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from monitor.models import synthetic

from monitor.config import demo_cell_path
from tests.helpers import free_port
from tests.processes import Service, empty_cell_video

ROOT = Path(__file__).resolve().parents[1]


def _cpu_s(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def _viewer(base: str, stop: threading.Event, counts: dict) -> None:
    next_state = next_image = time.monotonic()
    while not stop.is_set():
        now = time.monotonic()
        for url, due, period in ((base + "/api/state", next_state, 0.3),
                                 (base + "/api/live/cam0.jpg", next_image, 0.7)):
            if now >= due:
                try:
                    urllib.request.urlopen(url, timeout=5).read()
                    counts[url.rsplit("/", 1)[-1]] = counts.get(url.rsplit("/", 1)[-1], 0) + 1
                except OSError:
                    counts["errors"] = counts.get("errors", 0) + 1
                if period == 0.3:
                    next_state = now + period
                else:
                    next_image = now + period
        stop.wait(0.02)


def _phase(svc: Service, seconds: float) -> dict:
    arrivals: list[float] = []
    n_det = len(svc.detections)
    start_cmd = len(svc.commands)
    t0 = time.monotonic()
    # the peer's subscriber appends; time arrivals by polling the list length at 1 ms
    seen = start_cmd
    while time.monotonic() - t0 < seconds:
        n = len(svc.commands)
        if n > seen:
            arrivals.extend([time.monotonic()] * (n - seen))
            seen = n
        time.sleep(0.001)
    gaps = [1000 * (b - a) for a, b in itertools.pairwise(arrivals) if b > a]
    gaps.sort()
    return {"fps": (len(svc.detections) - n_det) / seconds, "commands": len(arrivals),
            "gap_p50": statistics.median(gaps) if gaps else float("nan"),
            "gap_p99": gaps[int(0.99 * (len(gaps) - 1))] if gaps else float("nan"),
            "gap_max": gaps[-1] if gaps else float("nan")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=15.0)
    args = ap.parse_args()
    model = synthetic.ensure_model()
    rows = []
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        video = empty_cell_video(tmp / "empty.mp4")
        svc = Service(tmp, model, str(video), extra=f'[zones]\nfile = "{demo_cell_path()}"\n')
        svc.config.write_text(svc.config.read_text().replace(
            f'source = "{video}"', f'source = "{video}"\nloop = true\nrealtime = true'))
        with svc:
            time.sleep(3.0)  # past start-up
            rows.append(("baseline", _phase(svc, args.seconds), ""))
            hport = free_port()
            log = (tmp / "console.log").open("w")
            console = subprocess.Popen(
                [sys.executable, "-m", "monitor", "console", "--cell", "t5",
                 "--connect", f"tcp/127.0.0.1:{svc.bus_port}", "--unauthenticated",
                 "--zones", str(demo_cell_path()), "--listen", f"127.0.0.1:{hport}"],
                stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONPATH": str(ROOT)})
            base = f"http://127.0.0.1:{hport}"
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                try:
                    urllib.request.urlopen(base + "/api/state", timeout=1).read()
                    break
                except OSError:
                    time.sleep(0.2)
            stop, counts = threading.Event(), {}
            viewer = threading.Thread(target=_viewer, args=(base, stop, counts), daemon=True)
            viewer.start()
            time.sleep(1.0)
            cpu0 = _cpu_s(console.pid)
            result = _phase(svc, args.seconds)
            cpu = (_cpu_s(console.pid) - cpu0) / args.seconds
            stop.set()
            viewer.join(5)
            rows.append(("one viewer", result,
                         f"console CPU {100 * cpu:.0f}% of a core; fetched {counts}"))
            console.send_signal(signal.SIGKILL)
            console.wait(10)
            log.close()
            rows.append(("console killed", _phase(svc, args.seconds), ""))
    print(f"{'phase':<15} {'fps':>6} {'cmds':>6} {'gap p50':>8} {'p99':>7} {'max':>7}  (ms)")
    for name, r, note in rows:
        print(f"{name:<15} {r['fps']:6.1f} {r['commands']:6d} {r['gap_p50']:8.1f} "
              f"{r['gap_p99']:7.1f} {r['gap_max']:7.1f}  {note}")


if __name__ == "__main__":
    main()
