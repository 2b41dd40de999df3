"""Adapters: a command change on the bus -> visible to the robot side, median and p99.

Run: python benchmarks/adapters.py [--changes 200] [ROW ...]

A signed SafetyBus runs in this process; each adapter runs as its own process (`python -m
monitor bridge KIND`, its default tick of 20 ms) and a client of its protocol reads in a tight
loop here. For each change the bus gets a new command (SLOW with a new speed scale, so every
change is distinguishable) and the time from just before ``publish_command`` to the first read
that shows it is recorded. Both clocks are this process's CLOCK_MONOTONIC.

Rows are functions in ``ROWS`` (one per adapter kind): each takes the parsed args and returns a
dict with ``adapter``, ``n``, ``median_ms``, ``p99_ms`` and ``note``. Benchmarks measure; they
are not tests. Close other work first: the machine has 2 cores.
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
CELL = "bench"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _p99(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))]


def _signed_bus(tmp: Path):
    from monitor.bus.session import BusConfig, SafetyBus
    from monitor.wire.signing import new_key_pair

    private, public, _ = new_key_pair(tmp / "monitor.key")
    port = _free_port()
    bus = SafetyBus(BusConfig(cell=CELL, instance="mon-bench", listen=(f"tcp/127.0.0.1:{port}",),
                              heartbeat_hz=20.0, ttl_ms=300, signing_key=str(private),
                              stall_timeout=3600.0)).__enter__()
    return bus, port, public


def _adapter(kind: str, zport: int, public: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "monitor", "bridge", kind, "--connect", f"tcp/127.0.0.1:{zport}",
         "--cell", CELL, "--monitor-key", str(public), "--ttl-ms", "1000", *extra],
        cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, stderr=subprocess.DEVNULL)


def _measure(publish: Callable[[float], None], seen: Callable[[], int | None],
             changes: int) -> tuple[list[float], list[float]]:
    """(latencies ms, read durations ms): publish SLOW with scale k/1000, read until seen."""
    lat, reads = [], []
    for i in range(changes):
        per_mille = 100 + (i % 2) * 400 + (i % 7)  # every change differs from the one before
        t0 = time.monotonic()
        publish(per_mille / 1000.0)
        while True:
            r0 = time.monotonic()
            value = seen()
            reads.append((time.monotonic() - r0) * 1000.0)
            if value == per_mille:
                lat.append((time.monotonic() - t0) * 1000.0)
                break
            if time.monotonic() - t0 > 5.0:
                raise RuntimeError(f"change {i} not visible within 5 s")
        time.sleep(0.03)
    return lat, reads


def plc_row(args: argparse.Namespace) -> dict:
    """`monitor bridge plc`: a pymodbus client reads the speed_scale register (FC3)."""
    from pymodbus.client import ModbusTcpClient

    from monitor.adapters import modbus_map as mm
    from monitor.policy import Command, Reason

    with tempfile.TemporaryDirectory() as tmp:
        bus, zport, public = _signed_bus(Path(tmp))
        mport = _free_port()
        proc = _adapter("plc", zport, public, "--modbus-listen", f"127.0.0.1:{mport}")
        client = ModbusTcpClient("127.0.0.1", port=mport, timeout=2, retries=0)
        try:
            deadline = time.monotonic() + 30
            while not client.connect():
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise RuntimeError("the plc adapter did not come up")
                time.sleep(0.1)
            scale = mm.ADDRESS["speed_scale"]

            def seen() -> int | None:
                r = client.read_holding_registers(scale, count=1, device_id=1)
                return None if r.isError() else r.registers[0]

            def publish(s: float) -> None:
                bus.publish_command(Command("SLOW", s, (Reason("warning_zone", "bench"),)))

            publish(0.05)  # the first command (and the adapter's liveliness) before timing
            while seen() != 50:
                time.sleep(0.01)
            lat, reads = _measure(publish, seen, args.changes)
        finally:
            client.close()
            proc.terminate()
            proc.wait(10)
            bus.close()
    return {"adapter": "plc (Modbus TCP)", "n": len(lat), "median_ms": statistics.median(lat),
            "p99_ms": _p99(lat), "note": f"adapter tick 20 ms; a read takes "
            f"{statistics.median(reads):.2f} ms (median)"}


# one function per adapter kind; other kinds append their rows after this one
ROWS: list[Callable[[argparse.Namespace], dict]] = [plc_row]


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--changes", type=int, default=200, help="command changes per row")
    p.add_argument("rows", nargs="*", help="row names (plc, ...; default all)")
    args = p.parse_args(argv)
    rows = [r for r in ROWS if not args.rows or r.__name__.removesuffix("_row") in args.rows]
    print("| adapter | changes | median ms | p99 ms | note |\n|---|---|---|---|---|")
    for row in rows:
        try:
            r = row(args)
        except Exception as exc:  # one row that cannot run never hides the others
            print(f"| {row.__name__} | - | - | - | failed: {exc} |", flush=True)
            continue
        print(f"| {r['adapter']} | {r['n']} | {r['median_ms']:.1f} | {r['p99_ms']:.1f} | "
              f"{r['note']} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
