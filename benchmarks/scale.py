"""N cells x M monitors through one `monitor router` on this machine: command latency at the
consumers, router CPU and messages per second as N grows.

Run: python benchmarks/scale.py [--cells 1,10,50] [--monitors 2] [--seconds 12]

What runs (all on 127.0.0.1, real Zenoh, real SafetyBus):

* one `monitor router --listen tcp/127.0.0.1:<port>` process (the hub of docs/scaling.md);
* N x M monitors, each a real ``SafetyBus`` (client of the router, Ed25519-signed commands)
  driven by a synthetic frame loop at ``--fps`` (10): every frame hands in the current command
  (it changes RUN <-> SLOW every ``--change-s`` s, at a random phase per monitor) and publishes
  a small detections message (one person). The bus's heartbeat repeats the command at 10 Hz.
  NO cameras and NO detector: this measures the bus and the router, not the monitor's pipeline
  (docs/capacity.md measures that). The monitors are batched into ``--publishers`` (2) child
  processes (the machine has 2 cores);
* one consumer process: one Zenoh session per cell (the cell's robot controller) subscribing to
  its cell's command keys and verifying every signature, plus one dashboard session
  subscribing to every cell's detections.

Latency is ``mono`` in the command's envelope (CLOCK_MONOTONIC, taken in the monitor before
JSON encoding and signing) to the consumer's callback after the signature is verified (the same
clock: one host). It includes signing, two hops through the router, verification and the
Python callback, under whatever else the machine runs (the load average is printed).
Router CPU is the router process's utime + stime (/proc/<pid>/stat) over the window, in % of
one core. Two monitors of one cell have their own roles (``[bus] role = "m<j>"``: keys
``workcell/<cell>/safety/m<j>/...``, docs/consumer.md): one monitor per role is enforced.
"""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing
import os
import random
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

CLK_TCK = os.sysconf("SC_CLK_TCK")


def cell_name(i: int) -> str:
    return f"cell{i:03d}"


def role(j: int) -> str:
    return f"m{j}"


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process (all its threads), in seconds."""
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def _publishers(port: int, monitors: list[tuple[int, int]], key: str, fps: float,
                change_s: float, ready, stop) -> None:
    """Run many SafetyBus monitors in this process with one frame loop for all of them."""
    import numpy as np

    from monitor.bus.session import BusConfig, SafetyBus
    from monitor.policy import Command, Reason
    from monitor.types import FrameInfo, Persons, ZoneHit, ZoneReport

    buses = []
    try:
        for i, j in monitors:
            cfg = BusConfig(cell=cell_name(i), role=role(j), instance=f"mon-{i}-{j}",
                            mode="client", connect=(f"tcp/127.0.0.1:{port}",),
                            signing_key=key)
            # startup_check_s=0: skip the one-monitor-per-cell query at start (1 s each);
            # the steady state is what is measured
            buses.append(SafetyBus(cfg, startup_check_s=0).__enter__())
        run = Command("RUN", 1.0, ())
        slow = Command("SLOW", 0.5, (Reason("warning_zone", "person 0 in zone W1",
                                            zone_id="W1", person=0),))
        rng = random.Random(os.getpid())
        phase = [rng.uniform(0, change_s) for _ in buses]
        box = np.array([[200.0, 120.0, 260.0, 300.0]], np.float32)
        score = np.array([0.8], np.float32)
        report = ZoneReport(hits=(ZoneHit("W1", "warning", 0, 0.5, 1.0),))
        ready.set()
        period, seq = 1.0 / fps, 0
        next_t = time.monotonic()
        while not stop.is_set():
            now = time.monotonic()
            for bus, ph in zip(buses, phase, strict=True):
                bus.publish_command(slow if int((now + ph) / change_s) % 2 else run)
                bus.publish_detections(Persons(box, score, FrameInfo("cam0", seq, now, 640,
                                                                     480)), report)
            seq += 1
            next_t += period
            delay = next_t - time.monotonic()
            if delay < -period:  # fell behind: restart the grid (the bus's heartbeat goes on)
                next_t, delay = time.monotonic(), 0.0
            time.sleep(max(0.0, delay))
    finally:
        # the frame loop has ended: the heartbeats' "stalled" STOPs while the others close are
        # expected here (in the window they are counted by the consumer)
        logging.getLogger("monitor.bus.session").setLevel(logging.ERROR)
        for bus in buses:
            bus.close()


def _consumer(port: int, n_cells: int, public_key: str, ready, window, out) -> None:
    """One session per cell (its controller) + one dashboard session; results into ``out``."""
    from monitor.bus.session import BusConfig, open_session
    from monitor.wire.signing import load_public_key, verify

    public = load_public_key(public_key)
    lock = threading.Lock()
    lat: list[float] = []
    changes: list[float] = []
    counts = {"commands": 0, "detections": 0, "bad_signature": 0, "stalled": 0}

    def in_window(now: float) -> bool:
        return window[0] > 0 and window[0] <= now <= window[1]

    def on_command(sample) -> None:
        payload = sample.payload.to_bytes()
        sig = sample.attachment.to_bytes() if sample.attachment is not None else None
        ok = verify(public, str(sample.key_expr), payload, sig)
        now = time.monotonic()
        if not in_window(now):
            return
        body = json.loads(payload)
        with lock:
            if not ok:
                counts["bad_signature"] += 1
                return
            counts["commands"] += 1
            ms = (now - body["mono"]) * 1000.0
            lat.append(ms)
            if not body["heartbeat"]:
                changes.append(ms)
            if any(r["code"] == "stalled" for r in body["reasons"]):
                counts["stalled"] += 1

    def on_detections(sample) -> None:
        if in_window(time.monotonic()):
            with lock:
                counts["detections"] += 1

    sessions = []
    try:
        for i in range(n_cells):
            s = open_session(BusConfig(cell=cell_name(i), instance=f"ctl-{i}", mode="client",
                                       connect=(f"tcp/127.0.0.1:{port}",)))
            s.declare_subscriber(f"workcell/{cell_name(i)}/safety/*/command", on_command)
            sessions.append(s)
        dash = open_session(BusConfig(cell="dashboard", instance="dashboard", mode="client",
                                      connect=(f"tcp/127.0.0.1:{port}",)))
        dash.declare_subscriber("workcell/*/safety/**/detections", on_detections)
        sessions.append(dash)
        ready.set()
        while window[1] == 0 or time.monotonic() < window[1] + 0.5:
            time.sleep(0.05)
        with lock:
            out.put({"lat": lat, "changes": changes, **counts})
    finally:
        for s in sessions:
            s.close()


def _pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


def run(n_cells: int, monitors: int, seconds: float, fps: float, change_s: float,
        n_publishers: int, key: str) -> dict:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    router = subprocess.Popen([sys.executable, "-m", "monitor", "router", "--listen",
                               f"tcp/127.0.0.1:{port}"], stderr=subprocess.PIPE, text=True,
                              env=env)
    ctx = multiprocessing.get_context("spawn")
    stop = ctx.Event()
    window = ctx.Array("d", [0.0, 0.0])
    out = ctx.Queue()
    procs = []
    try:
        if "listening" not in router.stderr.readline():
            raise SystemExit("monitor router did not start")
        consumer_ready = ctx.Event()
        consumer = ctx.Process(target=_consumer, args=(port, n_cells, key + ".pub",
                                                       consumer_ready, window, out))
        consumer.start()
        procs.append(consumer)
        consumer_ready.wait(120)
        pairs = [(i, j) for i in range(n_cells) for j in range(monitors)]
        n_proc = max(1, min(n_publishers, len(pairs)))
        readies = []
        for k in range(n_proc):
            ready = ctx.Event()
            p = ctx.Process(target=_publishers, args=(port, pairs[k::n_proc], key, fps,
                                                      change_s, ready, stop))
            p.start()
            procs.append(p)
            readies.append(ready)
        for ready in readies:
            if not ready.wait(180):
                raise SystemExit("the monitors did not start within 180 s")
        time.sleep(2.0)  # warm-up: links, declarations, first heartbeats
        load = os.getloadavg()[0]
        cpu0 = {p.pid: cpu_seconds(p.pid) for p in [router, *procs]}
        t0 = time.monotonic()
        window[0], window[1] = t0, t0 + seconds
        time.sleep(seconds)
        cpu1 = {pid: cpu_seconds(pid) for pid in cpu0}
        t1 = time.monotonic()
        res = out.get(timeout=60)
    finally:
        stop.set()
        for p in procs:
            p.join(30)
            if p.exitcode is None:
                p.kill()
        router.terminate()
        try:
            router.wait(10)
        except subprocess.TimeoutExpired:
            router.kill()
    span = t1 - t0
    pub_cpu = sum(cpu1[p.pid] - cpu0[p.pid] for p in procs[1:]) / span * 100
    return {
        "cells": n_cells, "monitors": n_cells * monitors, "load": load,
        "cmd_rate": res["commands"] / seconds, "det_rate": res["detections"] / seconds,
        "p50": _pct(res["lat"], 0.50), "p99": _pct(res["lat"], 0.99),
        "max": max(res["lat"], default=float("nan")),
        "chg_p50": _pct(res["changes"], 0.50), "chg_p99": _pct(res["changes"], 0.99),
        "n_changes": len(res["changes"]),
        "router_cpu": (cpu1[router.pid] - cpu0[router.pid]) / span * 100,
        "pub_cpu": pub_cpu,
        "consumer_cpu": (cpu1[procs[0].pid] - cpu0[procs[0].pid]) / span * 100,
        "bad": res["bad_signature"], "stalled": res["stalled"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", default="1,10,50", help="comma-separated N (default 1,10,50)")
    parser.add_argument("--monitors", type=int, default=2, help="monitors per cell (default 2)")
    parser.add_argument("--seconds", type=float, default=12.0,
                        help="measuring window per N (default 12)")
    parser.add_argument("--fps", type=float, default=10.0,
                        help="synthetic frames per second per monitor (default 10)")
    parser.add_argument("--change-s", type=float, default=2.0,
                        help="the command changes RUN <-> SLOW every this many s (default 2)")
    parser.add_argument("--publishers", type=int, default=2,
                        help="child processes the monitors are batched into (default 2)")
    args = parser.parse_args()
    from monitor.wire.signing import new_key_pair

    key = str(new_key_pair(Path(tempfile.mkdtemp(prefix="bench-scale-")) / "monitor.key")[0])
    started = time.monotonic()
    rows = [run(int(n), args.monitors, args.seconds, args.fps, args.change_s, args.publishers,
                key) for n in args.cells.split(",")]
    print(f"{args.monitors} monitors per cell, {args.fps:g} frames/s each (heartbeat 10 Hz, "
          f"a change every {args.change_s:g} s, one small detections message per frame); "
          f"{args.seconds:g} s window per row; {os.cpu_count()} cores; "
          f"total {time.monotonic() - started:.0f} s")
    print()
    print("| cells | monitors | commands/s at consumers | detections/s | latency p50 ms | "
          "p99 ms | max ms | changes p50 / p99 ms | router CPU % of a core | monitors' CPU % "
          "| consumers' CPU % | load avg | stalled / bad sig |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['cells']} | {r['monitors']} | {r['cmd_rate']:.0f} | {r['det_rate']:.0f} | "
              f"{r['p50']:.2f} | {r['p99']:.2f} | {r['max']:.1f} | "
              f"{r['chg_p50']:.2f} / {r['chg_p99']:.2f} | {r['router_cpu']:.1f} | "
              f"{r['pub_cpu']:.0f} | {r['consumer_cpu']:.0f} | {r['load']:.1f} | "
              f"{r['stalled']} / {r['bad']} |", flush=True)


if __name__ == "__main__":
    main()
