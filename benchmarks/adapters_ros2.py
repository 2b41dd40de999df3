"""`monitor bridge ros2`: a command change on the monitor's bus -> visible to a ROS 2 node.

Run: python benchmarks/adapters_ros2.py [--changes 200] [--tick 0.02]

This process runs a signed SafetyBus on tcp/127.0.0.1 and a raw Zenoh subscriber on rmw_zenoh's
key of the speed override (what an rmw_zenoh subscriber declares), decoding each sample as CDR.
The adapter is the real command, ``monitor bridge ros2``, in its own process. The bus alternates
RUN (1.0) and SLOW (0.5) every 150 ms; each change is timed from just before
``publish_command`` to the subscriber's callback that first shows the new override (both
CLOCK_MONOTONIC of this process). The adapter polls its inbox between ticks, so the figure is
the transport plus up to one tick (``--tick``, 20 ms by default) plus the signature check.

``ros2_row`` returns one row for a table of all adapters (benchmarks/adapters.py).
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def ros2_row(changes: int = 200, tick: float = 0.02) -> dict:
    from monitor.adapters import ros2_wire as wire
    from monitor.bus.session import BusConfig, SafetyBus, open_session
    from monitor.policy import Command
    from monitor.wire.signing import new_key_pair

    with tempfile.TemporaryDirectory() as tmp:
        private, public, _ = new_key_pair(Path(tmp) / "monitor.key")
        port = _free_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        cfg = BusConfig(cell="bench", instance="mon-bench", listen=(endpoint,),
                        heartbeat_hz=10.0, ttl_ms=1000, signing_key=str(private))
        key = wire.data_key(0, "/workcell/bench/speed_override", "std_msgs/msg/Float64")
        seen: list[tuple[float, float]] = []
        cond = threading.Condition()

        def on_sample(sample) -> None:
            t = time.monotonic()
            raw = sample.payload.to_bytes()
            if raw[:4] != wire.CDR_LE_HEADER or sample.attachment is None:
                return
            wire.parse_attachment(sample.attachment.to_bytes())
            with cond:
                seen.append((t, struct.unpack_from("<d", raw, 4)[0]))
                cond.notify_all()

        env = dict(os.environ, PYTHONPATH=str(ROOT))
        with SafetyBus(cfg) as bus, open_session(BusConfig(
                cell="bench", instance="rosnode", connect=(endpoint,))) as ros:
            sub = ros.declare_subscriber(key, on_sample)
            adapter = subprocess.Popen(
                [sys.executable, "-m", "monitor", "bridge", "ros2", "--cell", "bench",
                 "--connect", endpoint, "--monitor-key", str(public), "--tick", str(tick),
                 "--ttl-ms", "1000"], env=env, stderr=subprocess.DEVNULL)
            try:
                bus.publish_command(Command("STOP", 0.0))
                deadline = time.monotonic() + 30
                while time.monotonic() < deadline and not seen:
                    time.sleep(0.05)
                if not seen:
                    raise RuntimeError("the adapter never published")
                time.sleep(0.5)
                lat = []
                for i in range(changes):
                    value = 1.0 if i % 2 == 0 else 0.5
                    with cond:
                        start_index = len(seen)
                    t0 = time.monotonic()
                    bus.publish_command(Command("RUN" if value == 1.0 else "SLOW", value))
                    with cond:
                        ok = cond.wait_for(lambda v=value, s=start_index: any(
                            x == v for _, x in seen[s:]), timeout=2.0)
                        if ok:
                            lat.append(next(t for t, x in seen[start_index:] if x == value)
                                       - t0)
                    time.sleep(0.15)
            finally:
                adapter.terminate()
                adapter.wait(10)
                sub.undeclare()
    lat_ms = sorted(x * 1000.0 for x in lat)
    return {"adapter": "ros2 (rmw_zenoh format)", "changes": changes, "seen": len(lat_ms),
            "tick_ms": tick * 1000.0, "median_ms": statistics.median(lat_ms),
            "p90_ms": lat_ms[int(0.90 * len(lat_ms))],
            "p99_ms": lat_ms[min(len(lat_ms) - 1, int(0.99 * len(lat_ms)))],
            "max_ms": lat_ms[-1], "load1": os.getloadavg()[0]}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--changes", type=int, default=200)
    p.add_argument("--tick", type=float, default=0.02)
    a = p.parse_args()
    row = ros2_row(a.changes, a.tick)
    print("| adapter | tick ms | changes seen | median ms | p90 ms | p99 ms | max ms | load |")
    print("|---|---|---|---|---|---|---|---|")
    print(f"| {row['adapter']} | {row['tick_ms']:g} | {row['seen']}/{row['changes']} | "
          f"{row['median_ms']:.1f} | {row['p90_ms']:.1f} | {row['p99_ms']:.1f} | "
          f"{row['max_ms']:.1f} | {row['load1']:.1f} |")
    return 0 if row["seen"] == row["changes"] else 1


if __name__ == "__main__":
    sys.exit(main())
