"""OPC UA output latency: a command change on the bus until an OPC UA client sees it.

Run: PYTHONPATH=. python benchmarks/adapters_opcua.py [--changes 200] [--mode subscription]

A signed SafetyBus in this process (the monitor), `monitor bridge opcua` in its own process
(the adapter, default 20 ms tick), an asyncua client on 127.0.0.1. The bus alternates RUN and
SLOW every 150 ms; the latency is from ``publish_command`` to the client seeing the new
``State``: by a subscription (sampling 0 ms, publishing interval 10 ms) or by polling a read
every 5 ms. Both ends read CLOCK_MONOTONIC of the same host. Expect about one adapter tick
(the follower's grid) + the publishing interval; the figures depend on the machine's load.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path


def opcua_row(changes: int = 200, mode: str = "subscription", tick: float = 0.02) -> dict:
    """The benchmark's row: median and p99 (ms) of command change -> visible in OPC UA."""
    from asyncua import Client, ua

    from monitor.adapters.opcua import NAMESPACE, node_id
    from monitor.bus.session import BusConfig, SafetyBus
    from monitor.policy import Command, Reason
    from monitor.wire.signing import new_key_pair
    from tests.helpers import free_port

    tmp = Path(tempfile.mkdtemp(prefix="opcua-bench-"))
    private, public, _ = new_key_pair(tmp / "monitor.key")
    zport, oport, cell = free_port(), free_port(), "bench"
    url = f"opc.tcp://127.0.0.1:{oport}/bench"
    cfg = BusConfig(cell=cell, instance="mon-bench", listen=(f"tcp/127.0.0.1:{zport}",),
                    heartbeat_hz=20.0, ttl_ms=500, signing_key=str(private))
    commands = {2: Command("RUN", 1.0), 1: Command("SLOW", 0.5, (Reason("warning_zone", "w",
                                                                        zone_id="W"),))}
    with SafetyBus(cfg) as bus:
        current = [commands[1]]
        stop = threading.Event()

        def pipeline() -> None:  # the monitor's loop: the current command every 50 ms
            while not stop.wait(0.05):
                bus.publish_command(current[0])

        threading.Thread(target=pipeline, daemon=True).start()
        adapter = subprocess.Popen(
            [sys.executable, "-m", "monitor", "bridge", "opcua", "--cell", cell, "--connect",
             f"tcp/127.0.0.1:{zport}", "--monitor-key", str(public), "--endpoint", url,
             "--tick", str(tick)], stderr=subprocess.DEVNULL)
        try:
            lat = asyncio.run(_measure(url, commands, current, bus, changes, mode,
                                       Client, ua, NAMESPACE, node_id("State")))
        finally:
            stop.set()
            adapter.terminate()
            adapter.wait(timeout=10)
    lat.sort()
    return {"row": f"opcua ({mode})", "changes": len(lat),
            "median_ms": round(statistics.median(lat), 1),
            "p99_ms": round(lat[min(len(lat) - 1, int(0.99 * len(lat)))], 1),
            "max_ms": round(lat[-1], 1)}


async def _measure(url, commands, current, bus, changes, mode, Client, ua, namespace, sid):
    deadline = time.monotonic() + 60
    while True:  # the adapter process is starting
        try:
            client = Client(url, timeout=5)
            await client.connect()
            break
        except Exception:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)
    try:
        idx = await client.get_namespace_index(namespace)
        node = client.get_node(f"ns={idx};s={sid}")
        seen: dict[int, float] = {}
        event = asyncio.Event()
        loop = asyncio.get_running_loop()

        class Handler:
            def datachange_notification(self, n, value, data) -> None:
                seen[value] = time.monotonic()
                loop.call_soon_threadsafe(event.set)

        if mode == "subscription":
            sub = await client.create_subscription(ua.CreateSubscriptionParameters(
                RequestedPublishingInterval=10, RequestedLifetimeCount=1000,
                RequestedMaxKeepAliveCount=100, PublishingEnabled=True), Handler())
            await sub.subscribe_data_change(node, sampling_interval=0)

        async def until(state: int, timeout: float) -> float | None:
            end = time.monotonic() + timeout
            while time.monotonic() < end:
                if mode == "subscription":
                    if state in seen:
                        return seen.pop(state)
                    event.clear()
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(event.wait(), 0.05)
                else:
                    if await node.read_value() == state:
                        return time.monotonic()
                    await asyncio.sleep(0.005)
            return None

        assert await until(1, 30.0) is not None, "the adapter never showed the monitor's SLOW"
        lat: list[float] = []
        state = 1
        for _ in range(changes):
            state = 2 if state == 1 else 1
            seen.clear()
            t0 = time.monotonic()
            current[0] = commands[state]
            bus.publish_command(commands[state])
            t1 = await until(state, 2.0)
            if t1 is not None:
                lat.append((t1 - t0) * 1000.0)
            await asyncio.sleep(0.15)
        return lat
    finally:
        await client.disconnect()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--changes", type=int, default=200)
    ap.add_argument("--mode", choices=["subscription", "polling", "both"], default="both")
    args = ap.parse_args()
    for mode in (["subscription", "polling"] if args.mode == "both" else [args.mode]):
        print(opcua_row(args.changes, mode), flush=True)


if __name__ == "__main__":
    main()
