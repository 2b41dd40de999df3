"""Command latency between two processes over tcp/127.0.0.1 while detections flow.

Run: /work/venv/bin/python benchmarks/bus.py [--commands 1000]

A publisher process (multiprocessing "spawn") runs a SafetyBus and hands it a changing command
at 200 Hz (every one goes out at once) while a second thread publishes detections. This process
subscribes like a robot controller and measures publish-to-receive latency from the envelope's
``mono`` stamp (taken inside ``publish_command``, before JSON encoding) to the subscriber
callback (both CLOCK_MONOTONIC of the same host). Target: p99 < 2 ms on loopback.

With signing on, the monitor signs every command (Ed25519) and the subscriber verifies the
signature before taking the receive time, so the latency includes both. A micro-benchmark
prints the cost of signing and verifying one command payload (µs).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import socket
import statistics
import threading
import time


def _raw_publisher(port: int, n_commands: int, cmd_hz: float) -> None:
    """Baseline: a bare Zenoh publisher with the same QoS and a similar JSON payload."""
    import zenoh

    from monitor.bus.session import BusConfig, BusKeys, open_session

    cfg = BusConfig(cell="bench", instance="raw", listen=(f"tcp/127.0.0.1:{port}",))
    with open_session(cfg) as session:
        pub = session.declare_publisher(
            BusKeys.of("workcell/bench/").command, priority=zenoh.Priority.REAL_TIME,
            express=True, congestion_control=zenoh.CongestionControl.BLOCK)
        while not pub.matching_status.matching:
            time.sleep(0.01)
        time.sleep(0.5)
        period = 1.0 / cmd_hz
        next_t = time.monotonic()
        for i in range(n_commands):
            pub.put(json.dumps({"seq": i, "mono": time.monotonic(), "heartbeat": False,
                                "state": "RUN", "reasons": []}).encode())
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))
        time.sleep(0.3)


def _publisher(port: int, n_commands: int, cmd_hz: float, det_hz: float, n_boxes: int,
               key: str | None = None) -> None:
    import numpy as np

    from monitor.bus.session import BusConfig, SafetyBus
    from monitor.policy import Command, Reason
    from monitor.types import FrameInfo, Persons, ZoneHit, ZoneReport

    cfg = BusConfig(cell="bench", instance="bench", listen=(f"tcp/127.0.0.1:{port}",),
                    signing_key=key)
    with SafetyBus(cfg) as bus:
        while not bus._pub_command.matching_status.matching:
            time.sleep(0.01)
        time.sleep(0.5)
        stop = threading.Event()

        def detections() -> None:
            rng = np.random.default_rng(0)
            boxes = rng.uniform(0, 600, (n_boxes, 4)).astype(np.float32)
            report = ZoneReport(hits=tuple(ZoneHit("W1", "warning", i, 0.5, 1.0)
                                           for i in range(min(n_boxes, 4))))
            seq = 0
            while not stop.is_set():
                seq += 1
                persons = Persons(boxes, np.full(n_boxes, 0.8, np.float32),
                                  FrameInfo("cam0", seq, time.monotonic(), 1920, 1080))
                bus.publish_detections(persons, report)
                stop.wait(1.0 / det_hz)

        thread = threading.Thread(target=detections, daemon=True)
        if det_hz > 0:
            thread.start()
        commands = [Command("RUN", 1.0, ()),
                    Command("SLOW", 0.5, (Reason("warning_zone", "person 0 in zone W1",
                                                 zone_id="W1", person=0),))]
        period = 1.0 / cmd_hz
        next_t = time.monotonic()
        for i in range(n_commands):
            bus.publish_command(commands[i % 2])
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))
        time.sleep(0.3)
        stop.set()


def run(n_commands: int, det_hz: float, n_boxes: int, raw: bool = False,
        key: str | None = None) -> dict:
    import zenoh

    from monitor.bus.session import BusConfig, BusKeys, open_session
    from monitor.wire.signing import load_public_key, verify

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    keys = BusKeys.of("workcell/bench/")
    lat: list[float] = []
    recv: list[float] = []  # receive times of the measured commands
    dets = [0]

    public = load_public_key(key + ".pub") if key else None
    bad = [0]

    def on_cmd(sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        if public is not None:
            sig = sample.attachment.to_bytes() if sample.attachment is not None else None
            if not verify(public, keys.command, payload, sig):
                bad[0] += 1
                return
        now = time.monotonic()
        body = json.loads(payload)
        shutdown = any(r.get("code") == "shutdown" for r in body["reasons"])
        if not body["heartbeat"] and not shutdown:
            lat.append((now - body["mono"]) * 1000.0)
            recv.append(now)

    def on_det(sample: zenoh.Sample) -> None:
        if lat:  # count only while commands flow
            dets[0] += 1

    ctx = multiprocessing.get_context("spawn")
    if raw:
        proc = ctx.Process(target=_raw_publisher, args=(port, n_commands, 200.0))
    else:
        proc = ctx.Process(target=_publisher, args=(port, n_commands, 200.0, det_hz, n_boxes,
                                                    key))
    proc.start()
    cfg = BusConfig(cell="bench", instance="ctl", connect=(f"tcp/127.0.0.1:{port}",))
    with open_session(cfg) as session:
        session.declare_subscriber(keys.command, on_cmd)
        session.declare_subscriber(keys.detections, on_det)
        proc.join(timeout=120)
    if proc.exitcode != 0:
        raise SystemExit(f"publisher failed with exit code {proc.exitcode}")
    if bad[0]:
        raise SystemExit(f"{bad[0]} commands failed signature verification")
    lat.sort()
    return {"n": len(lat), "median": statistics.median(lat),
            "p99": lat[min(len(lat) - 1, int(0.99 * len(lat)))], "max": lat[-1],
            "det_rate": dets[0] / max(recv[-1] - recv[0], 1e-3)}


def signing_cost(n: int = 5000) -> tuple[float, float]:
    """µs to sign and to verify one typical command payload (median of ``n``)."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    from monitor.wire.signing import Signer, verify

    signer = Signer(Ed25519PrivateKey.generate())
    public = signer.key.public_key()
    key = "workcell/bench/safety/command"
    payload = json.dumps({"schema": "workcell.safety.command/1", "cell": "bench", "seq": 1834,
                          "mono": 5121.337, "wall": 1.79e9, "ttl_ms": 300, "config_hash": "9f2c",
                          "instance": "monitor-host-4121-9a0e", "boot": "4dee5337" * 4,
                          "state": "SLOW", "speed_scale": 0.4, "since": 5120.9,
                          "latched": False, "heartbeat": True,
                          "reasons": [{"code": "warning_zone", "message": "person 0 in W1",
                                       "zone_id": "W1", "person": 0}]}).encode()
    sign_t, verify_t = [], []
    for _ in range(n):
        t = time.perf_counter()
        sig = signer.sign(key, payload)
        sign_t.append(time.perf_counter() - t)
        t = time.perf_counter()
        if not verify(public, key, payload, sig):
            raise SystemExit("verification failed")
        verify_t.append(time.perf_counter() - t)
    return statistics.median(sign_t) * 1e6, statistics.median(verify_t) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--commands", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3,
                        help="runs per scenario, interleaved; the table shows medians")
    args = parser.parse_args()
    import tempfile

    from monitor.wire.signing import new_key_pair

    sign_us, verify_us = signing_cost()
    print("| Ed25519 per command payload | median µs |")
    print("|---|---:|")
    print(f"| sign (monitor) | {sign_us:.1f} |")
    print(f"| verify (consumer) | {verify_us:.1f} |")
    print()
    tmp = tempfile.mkdtemp(prefix="bench-bus-")
    key = str(new_key_pair(f"{tmp}/monitor.key")[0])
    scenarios = [
        ("baseline: bare Zenoh put, same QoS", 0.0, 0, True, None),
        ("SafetyBus commands only, unsigned", 0.0, 0, False, None),
        ("SafetyBus commands only, signed + verified", 0.0, 0, False, key),
        ("SafetyBus signed + detections 30 Hz, 5 persons", 30.0, 5, False, key),
        ("SafetyBus signed + detections 1 kHz, 50 persons", 1000.0, 50, False, key),
    ]
    results: dict[str, list[dict]] = {name: [] for name, *_ in scenarios}
    for _ in range(args.repeats):  # interleaved, so machine load hits every scenario alike
        for name, det_hz, n_boxes, raw, k in scenarios:
            results[name].append(run(args.commands, det_hz, n_boxes, raw, k))
    print(f"{args.repeats} runs x {args.commands} commands at 200 Hz; medians over runs "
          "(p99 range in brackets)")
    print("| scenario | received | median ms | p99 ms | max ms | detections/s |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, rs in results.items():
        def med(key, rs=rs):
            return statistics.median(r[key] for r in rs)

        p99s = sorted(r["p99"] for r in rs)
        print(f"| {name} | {min(r['n'] for r in rs)} / {args.commands} | {med('median'):.3f} | "
              f"{med('p99'):.3f} [{p99s[0]:.2f}-{p99s[-1]:.2f}] | {med('max'):.3f} | "
              f"{med('det_rate'):.0f} |", flush=True)


if __name__ == "__main__":
    main()
