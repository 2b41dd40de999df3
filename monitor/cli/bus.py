"""Bus commands: ``monitor watch``, ``monitor bridge otus``, ``monitor router``,
``monitor reset``, ``monitor status``.

Also runnable on its own: ``python -m monitor.cli.bus watch ...``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import queue
import signal
import socket
import sys
import threading
import time
from collections.abc import Iterator

import zenoh

from monitor.alerts import AlertLimiter, AlertLimits, alert_to_dict, pose_alert
from monitor.bus import (
    ALERT_SCHEMA,
    MODES,
    BusConfig,
    BusKeys,
    CommandWatchdog,
    Verdict,
    open_session,
    reset_payload,
)
from monitor.errors import ConfigError
from monitor.pose import OtusBridge, PoseLimits, Rejection, parse_host_port


def _add_zenoh_args(p: argparse.ArgumentParser, default_mode: str = "peer",
                    listen_flag: str = "--listen") -> None:
    g = p.add_argument_group("Zenoh")
    g.add_argument("--cell", default="cell1", help="cell name; keys are workcell/<cell>/...")
    g.add_argument("--prefix", help="key prefix (default workcell/<cell>/)")
    g.add_argument("--mode", choices=MODES, default=None,
                   help=f"session mode (default {default_mode}, or the --zenoh-config file's)")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/10.0.0.5:7447 (repeatable)")
    g.add_argument(listen_flag, dest="zlisten", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    g.add_argument("--zenoh-config", help="Zenoh JSON5 config file used as the base")
    g.add_argument("--scouting", action="store_true", help="enable multicast scouting")
    g.add_argument("--tls-ca", help="CA certificate (PEM) for tls/ endpoints")
    g.add_argument("--tls-cert", help="this side's certificate (PEM)")
    g.add_argument("--tls-key", help="this side's private key (PEM)")
    g.add_argument("--user", help="Zenoh user name (password from --password-file)")
    g.add_argument("--password-file", help="file whose first line is the Zenoh password")
    g.add_argument("--instance", help="instance id (default monitor-<hostname>)")
    p.set_defaults(default_mode=default_mode)


def _bus_config(args: argparse.Namespace, **over) -> BusConfig:
    password = None
    if args.password_file:
        try:
            with open(args.password_file, encoding="utf-8") as fh:
                password = fh.readline().rstrip("\n")
        except OSError as exc:
            raise ConfigError(f"{args.password_file}: cannot read the password: "
                              f"{exc.strerror}") from None
    kw = dict(
        cell=args.cell, prefix=args.prefix,
        mode=args.mode or (None if args.zenoh_config else args.default_mode),
        listen=tuple(args.zlisten), connect=tuple(args.connect),
        multicast_scouting=args.scouting, zenoh_config_file=args.zenoh_config,
        tls_root_ca=args.tls_ca, tls_cert=args.tls_cert, tls_key=args.tls_key,
        user=args.user, password=password,
    )
    if getattr(args, "instance", None):
        kw["instance"] = args.instance
    kw.update(over)
    return BusConfig(**kw)


@contextlib.contextmanager
def _stop_on_signals() -> Iterator[threading.Event]:
    """An event set by SIGINT/SIGTERM (handlers restored afterwards)."""
    stop = threading.Event()
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for s in old:
        signal.signal(s, lambda *_: stop.set())
    try:
        yield stop
    finally:
        for s, h in old.items():
            signal.signal(s, h)


# --- watch -----------------------------------------------------------------------------------


def _fmt_time() -> str:
    t = time.time()
    return time.strftime("%H:%M:%S", time.localtime(t)) + f".{int(t * 1000) % 1000:03d}"


def _reasons_text(command: dict | None) -> str:
    if not command:
        return ""
    return "; ".join(r.get("message", r.get("code", "")) for r in command.get("reasons", []))


def _emit(args, event: dict, text: str) -> None:
    if args.json:
        print(json.dumps(event, default=str), flush=True)
    else:
        print(f"{_fmt_time()} {text}", flush=True)


def cmd_watch(args: argparse.Namespace) -> int:
    bus = _bus_config(args)
    keys = BusKeys.of(bus.key_prefix)
    dog = CommandWatchdog(max_ttl_ms=args.ttl_ms, instance=args.follow,
                          require_liveliness=not args.no_liveliness)
    inbox: queue.SimpleQueue = queue.SimpleQueue()  # (kind, payload, attachment/alive, t_recv)
    clock = time.monotonic
    with _stop_on_signals() as stop, open_session(bus) as session:
        session.declare_subscriber(keys.command, lambda s: inbox.put(
            ("command", s.payload.to_bytes(), None, clock())))
        session.declare_subscriber(keys.alert, lambda s: inbox.put(
            ("alert", s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment else None,
             clock())))
        session.liveliness().declare_subscriber(keys.alive + "/*", lambda s: inbox.put(
            ("alive", str(s.key_expr), s.kind == zenoh.SampleKind.PUT, clock())),
            history=True)
        end = clock() + args.duration if args.duration else None
        shown: tuple | None = None
        while not stop.is_set() and (end is None or clock() < end):
            try:
                kind, payload, extra, t_recv = inbox.get(timeout=args.tick)
            except queue.Empty:
                kind = None
            if kind == "command":
                why = dog.on_command(payload, t_recv)
                if args.verbose or why:
                    body = _safe_json(payload)
                    _emit(args, {"event": "command", "mono": t_recv, "rejected": why,
                                 "body": body},
                          f"command seq={body.get('seq')} {body.get('state')} "
                          f"{'REJECTED ' + why if why else ''}")
            elif kind == "alert":
                body = _safe_json(payload)
                _emit(args, {"event": "alert", "mono": t_recv, "body": body,
                             "snapshot_bytes": len(extra) if extra else 0},
                      f"ALERT {body.get('severity', '?').upper()} {body.get('kind')} "
                      f"from {body.get('source')}: {body.get('message')}"
                      + (f" (+{body['repeat']} repeats)" if body.get("repeat") else "")
                      + (f" [snapshot {len(extra)} B]" if extra else ""))
            elif kind == "alive":
                dog.on_liveliness(payload, bool(extra))
                _emit(args, {"event": "liveliness", "mono": t_recv, "key": payload,
                             "alive": bool(extra)},
                      f"liveliness {payload} {'appeared' if extra else 'VANISHED'}")
            verdict = dog.verdict(clock())
            key = (verdict.state, verdict.speed_scale, verdict.code,
                   _reasons_text(verdict.command) if not verdict.code else "")
            if key != shown:
                shown = key
                _emit_verdict(args, verdict, clock())
    return 0


def _emit_verdict(args, v: Verdict, now: float) -> None:
    why = v.reason or _reasons_text(v.command)
    _emit(args, {"event": "verdict", "mono": now, "state": v.state, "speed_scale": v.speed_scale,
                 "code": v.code, "reason": v.reason, "seq": v.seq, "command": v.command},
          f"{v.state:<4} scale={v.speed_scale:.2f} seq={v.seq} {why}")


def _safe_json(payload: bytes) -> dict:
    try:
        body = json.loads(payload)
        return body if isinstance(body, dict) else {"value": body}
    except ValueError:
        return {"invalid": payload[:200].hex()}


# --- bridge otus -----------------------------------------------------------------------------


def cmd_bridge_otus(args: argparse.Namespace) -> int:
    host, port = parse_host_port(args.udp_listen)
    bus = _bus_config(args, instance=args.instance or f"otus-bridge-{socket.gethostname()}")
    keys = BusKeys.of(bus.key_prefix)
    limits = PoseLimits(max_speed_m_s=args.max_speed, max_accel_m_s2=args.max_accel,
                        quaternion_tolerance=args.quaternion_tolerance)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ConfigError(f"--listen {args.udp_listen}: cannot bind UDP: {exc.strerror}") from None
    limiter = AlertLimiter(AlertLimits(min_interval=args.alert_interval))
    seq = {"alert": 0}
    with sock, _stop_on_signals() as stop, open_session(bus) as session:
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
        bridge.run(stop)
        v = bridge.validator
        print(f"monitor bridge otus: {bridge.packets} packets, {v.accepted} published, "
              f"rejected {dict(v.rejected)}, {bridge.silences} silences", file=sys.stderr)
    return 0


# --- router, reset, status -----------------------------------------------------------------


def cmd_router(args: argparse.Namespace) -> int:
    bus = _bus_config(args)
    if not bus.listen and not args.zenoh_config:
        raise ConfigError("monitor router: give --listen ENDPOINT (e.g. tcp/0.0.0.0:7447) "
                          "or --zenoh-config")
    with _stop_on_signals() as stop, open_session(bus) as session:
        print(f"monitor router: zid {session.zid()} listening on {list(bus.listen)}",
              file=sys.stderr, flush=True)
        stop.wait()
    return 0


def cmd_reset(args: argparse.Namespace) -> int:
    bus = _bus_config(args, instance=args.instance or "operator")
    keys = BusKeys.of(bus.key_prefix)
    with open_session(bus) as session:
        pub = session.declare_publisher(keys.reset, encoding="application/json",
                                        priority=zenoh.Priority.INTERACTIVE_HIGH,
                                        congestion_control=zenoh.CongestionControl.BLOCK)
        deadline = time.monotonic() + args.timeout
        while not pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.02)
        if not pub.matching_status.matching:
            raise ConfigError(f"monitor reset: no monitor subscribes to {keys.reset}")
        pub.put(reset_payload(args.operator, args.request_id or f"{time.time():.3f}", args.note))
    print(f"reset request sent to {keys.reset} as {args.operator}; check `monitor status` "
          "or `monitor watch` for the outcome")
    return 0


def cmd_status(args: argparse.Namespace) -> int:
    bus = _bus_config(args, instance=args.instance or "status-query")
    keys = BusKeys.of(bus.key_prefix)
    answers = 0
    with open_session(bus) as session:
        for reply in session.get(keys.status, timeout=args.timeout):
            if reply.ok is not None:
                answers += 1
                print(json.dumps(json.loads(reply.ok.payload.to_bytes()), indent=2))
    if not answers:
        raise ConfigError(f"monitor status: no answer on {keys.status} within {args.timeout} s")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("watch", help="print commands and alerts; apply the consumer rule",
                              description="Reference consumer: reports STOP when no valid "
                              "command arrived within ttl, when seq goes backwards or when the "
                              "monitor's liveliness token vanishes.")
    _add_zenoh_args(p)
    p.add_argument("--ttl-ms", type=float, default=None,
                   help="cap on the commands' ttl_ms (default: trust the command's)")
    p.add_argument("--follow", metavar="INSTANCE", help="only accept this monitor instance")
    p.add_argument("--no-liveliness", action="store_true",
                   help="do not require the liveliness token (not recommended)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.add_argument("--verbose", "-v", action="store_true", help="print every command")
    p.add_argument("--duration", type=float, default=None, help="exit after this many seconds")
    p.add_argument("--tick", type=float, default=0.01, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_watch)

    bridge = subparsers.add_parser("bridge", help="bridge external streams onto the bus")
    bsub = bridge.add_subparsers(dest="bridge_kind", metavar="KIND", required=True)
    p = bsub.add_parser("otus", help="republish OTUS tracker UDP packets as pose samples")
    p.add_argument("--listen", dest="udp_listen", default="127.0.0.1:5400", metavar="HOST:PORT",
                   help="UDP address to receive OTUS packets on (default 127.0.0.1:5400)")
    _add_zenoh_args(p, listen_flag="--zenoh-listen")
    p.add_argument("--max-speed", type=float, default=PoseLimits.max_speed_m_s,
                   help="m/s, plausibility limit")
    p.add_argument("--max-accel", type=float, default=PoseLimits.max_accel_m_s2,
                   help="m/s², plausibility limit")
    p.add_argument("--quaternion-tolerance", type=float,
                   default=PoseLimits.quaternion_tolerance)
    p.add_argument("--pose-timeout", type=float, default=0.1,
                   help="s of UDP silence that raise a pose_silence alert (once per gap)")
    p.add_argument("--alert-interval", type=float, default=5.0,
                   help="s between two pose_rejected alerts (repeats are counted)")
    p.set_defaults(func=cmd_bridge_otus)

    p = subparsers.add_parser("router", help="run a Zenoh router until SIGINT/SIGTERM")
    _add_zenoh_args(p, default_mode="router")
    p.set_defaults(func=cmd_router)

    p = subparsers.add_parser("reset", help="ask the monitor to release a latched STOP")
    _add_zenoh_args(p)
    p.add_argument("--operator", required=True, help="operator id (logged)")
    p.add_argument("--request-id", default="")
    p.add_argument("--note", default="")
    p.add_argument("--timeout", type=float, default=3.0)
    p.set_defaults(func=cmd_reset)

    p = subparsers.add_parser("status", help="query the monitor's status")
    _add_zenoh_args(p)
    p.add_argument("--timeout", type=float, default=3.0)
    p.set_defaults(func=cmd_status)
