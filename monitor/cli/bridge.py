"""``monitor bridge otus`` (OTUS tracker UDP -> pose samples on the bus) and the ``bridge``
parser, where the robot-side kinds of ``monitor.cli.adapters`` register too."""

from __future__ import annotations

import argparse
import json
import socket
import sys
import threading
import time

import zenoh

from monitor.bus.session import ALERT_SCHEMA, BusKeys, default_instance, open_session
from monitor.cli.zenoh_args import add_zenoh_args, bounded, bus_config
from monitor.errors import ConfigError
from monitor.pose.stream import OtusBridge, PoseLimits, Rejection, parse_host_port
from monitor.pose.tracker_noise import TrackerConfig
from monitor.signals import Interrupted, StopSignals, call_interruptible, exit_if_stopped
from monitor.wire.alerts import AlertLimiter, AlertLimits, alert_to_dict, pose_alert


def cmd_bridge_otus(args: argparse.Namespace) -> int:
    with StopSignals(name="monitor bridge otus") as stop:
        return _bridge_otus(args, stop)


def _bridge_otus(args: argparse.Namespace, stop) -> int:
    host, port = parse_host_port(args.udp_listen)
    bus = bus_config(args, instance=args.instance or default_instance("otus-bridge"))
    keys = BusKeys.of(bus.key_prefix)
    # the same precision as the monitor's [tracker]: the bridge must not drop what it accepts
    noise = TrackerConfig(noise_mm=args.tracker_noise_mm, noise_deg=args.tracker_noise_deg)
    limits = PoseLimits(max_speed_m_s=args.max_speed, max_accel_m_s2=args.max_accel,
                        quaternion_tolerance=args.quaternion_tolerance, noise=noise)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ConfigError(f"--listen {args.udp_listen}: cannot bind UDP: {exc.strerror}") from None
    limiter = AlertLimiter(AlertLimits(min_interval=args.alert_interval))
    seq = {"alert": 0}
    try:
        session = call_interruptible(lambda: open_session(bus), stop)
    except Interrupted:
        sock.close()
        return 0
    with sock, bounded(session, "monitor bridge otus") as session:
        pubs = {
            "tracker/pose": session.declare_publisher(
                keys.pose, encoding="application/json", priority=zenoh.Priority.INTERACTIVE_HIGH,
                express=True, congestion_control=zenoh.CongestionControl.DROP),
            "tracker/pose/rejected": session.declare_publisher(
                keys.pose + "/rejected", encoding="application/json"),
        }
        pub_alert = session.declare_publisher(keys.alert, encoding="application/json",
                                              priority=zenoh.Priority.DATA_HIGH)

        def publish(suffix: str, payload: bytes) -> None:
            pubs[suffix].put(payload)

        def alert(bad: Rejection) -> None:
            a = pose_alert(bad, bus.instance, time.monotonic())
            repeat = limiter.admit(a, time.monotonic())
            if repeat is None:
                return
            seq["alert"] += 1
            body = {"schema": ALERT_SCHEMA, "seq": seq["alert"], "mono": time.monotonic(),
                    "wall": time.time(), "ttl_ms": bus.ttl_ms, "config_hash": "",
                    "instance": bus.instance, "boot": str(session.zid()),
                    **alert_to_dict(a, repeat)}
            pub_alert.put(json.dumps(body).encode())

        bridge = OtusBridge(sock, publish, alert, limits, instance=bus.instance,
                            pose_timeout=args.pose_timeout)
        print(f"monitor bridge otus: UDP {host}:{sock.getsockname()[1]} -> {keys.pose}",
              file=sys.stderr, flush=True)
        if not (bus.connect or bus.listen or bus.zenoh_config_file):
            print("monitor bridge otus: warning: no --connect, --zenoh-listen or --zenoh-config: "
                  "no monitor can reach this bridge" + (" unless multicast scouting finds one"
                                                        if bus.multicast_scouting else "")
                  + "; give --connect tcp/<monitor host>:7447", file=sys.stderr, flush=True)
        done = threading.Event()
        watcher = threading.Thread(target=_warn_unmatched, daemon=True, name="pose-matching",
                                   args=(pubs["tracker/pose"], keys.pose, args.unmatched_warn,
                                         stop, done))
        watcher.start()
        try:
            bridge.run(stop)
        finally:
            done.set()
            watcher.join(timeout=1.0)
        v = bridge.validator
        print(f"monitor bridge otus: {bridge.packets} packets, {v.accepted} published, "
              f"rejected {dict(v.rejected)}, {bridge.silences} silences", file=sys.stderr)
    return exit_if_stopped(stop)


def _warn_unmatched(publisher, key: str, after: float, stop, done: threading.Event) -> None:
    """Warn (stderr) when no subscriber has matched ``publisher`` for ``after`` seconds: the
    poses go nowhere (Zenoh matching status). Once per unmatched spell; a match clears it."""
    since, warned = time.monotonic(), False
    while not done.wait(0.1) and not stop.is_set():
        try:
            matched = publisher.matching_status.matching
        except Exception:  # the publisher is closing
            return
        now = time.monotonic()
        if matched:
            if warned:
                print(f"monitor bridge otus: a subscriber to {key} matched again",
                      file=sys.stderr, flush=True)
            since, warned = now, False
        elif not warned and now - since >= after:
            warned = True
            print(f"monitor bridge otus: warning: no subscriber to {key} for {after:g} s: the "
                  "poses go nowhere (is the monitor up, on this cell, with separation "
                  "monitoring on? check --connect and --cell)", file=sys.stderr, flush=True)

def register(subparsers) -> None:
    bridge = subparsers.add_parser("bridge", help="bridge external streams onto the bus")
    bsub = bridge.add_subparsers(dest="bridge_kind", metavar="KIND", required=True)
    p = bsub.add_parser("otus", help="republish OTUS tracker UDP packets as pose samples")
    p.add_argument("--listen", dest="udp_listen", default="127.0.0.1:5400", metavar="HOST:PORT",
                   help="UDP address to receive OTUS packets on (default 127.0.0.1:5400)")
    add_zenoh_args(p, listen_flag="--zenoh-listen")
    p.add_argument("--max-speed", type=float, default=PoseLimits.max_speed_m_s,
                   help=f"m/s, plausibility limit (default {PoseLimits.max_speed_m_s:g})")
    p.add_argument("--max-accel", type=float, default=PoseLimits.max_accel_m_s2,
                   help=f"m/s², plausibility limit (default {PoseLimits.max_accel_m_s2:g})")
    p.add_argument("--quaternion-tolerance", type=float,
                   default=PoseLimits.quaternion_tolerance,
                   help="allowed deviation of |q| from 1 (default "
                   f"{PoseLimits.quaternion_tolerance:g})")
    p.add_argument("--tracker-noise-mm", type=float, default=TrackerConfig.noise_mm,
                   help="the tracker's declared position precision, mm (1 sigma per axis, as "
                   "[tracker] noise_mm; default %(default)s)")
    p.add_argument("--tracker-noise-deg", type=float, default=TrackerConfig.noise_deg,
                   help="the tracker's declared orientation precision, degrees (1 sigma per "
                   "axis, as [tracker] noise_deg; default %(default)s)")
    p.add_argument("--pose-timeout", type=float, default=0.1,
                   help="s of UDP silence that raise a pose_silence alert (once per gap; "
                   "default 0.1)")
    p.add_argument("--unmatched-warn", type=float, default=5.0, metavar="S",
                   help="s without any subscriber to the pose samples before a warning "
                   "(default 5)")
    p.add_argument("--alert-interval", type=float, default=5.0,
                   help="s between two pose_rejected alerts (repeats are counted; default 5)")
    p.set_defaults(func=cmd_bridge_otus)
    from monitor.cli.adapters import register_bridges  # robot-side outputs (docs/adapters.md)

    register_bridges(bsub, add_zenoh_args)
