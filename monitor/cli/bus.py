"""Bus commands: ``monitor watch``, ``monitor bridge otus``, ``monitor router``,
``monitor reset``, ``monitor status``, ``monitor keys new``.

Also runnable on its own: ``python -m monitor.cli.bus watch ...``. Every command stops within
2 s of SIGINT/SIGTERM in every phase (``monitor.signals``); a second signal exits at once.
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import time
from pathlib import Path

import zenoh

from monitor.alerts import AlertLimiter, AlertLimits, alert_to_dict, pose_alert
from monitor.bus import (
    ALERT_SCHEMA,
    MODES,
    BusConfig,
    BusKeys,
    CommandWatchdog,
    Verdict,
    default_instance,
    open_session,
)
from monitor.cell_consumer import CellWatchdog, parse_expect, subscribe_cell
from monitor.consumer import DEFAULT_CLOCK_SYNC_MS
from monitor.errors import ConfigError
from monitor.inbox import DEFAULT_BOUND, Inbox
from monitor.pose import OtusBridge, PoseLimits, Rejection, parse_host_port
from monitor.resets import latch_of_status, request_reset, reset_payload
from monitor.signals import (
    Interrupted,
    StopSignals,
    call_interruptible,
    close_bounded,
    exit_if_stopped,
    wait_for_stop,
)
from monitor.signing import load_private_key, load_public_key, new_key_pair

# `monitor run` without a config listens here (monitor.config.DEMO_LISTEN); the operator
# commands connect here when no endpoint is given, so they find a default service on this host.
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
KEY_DIR = Path("~/.config/workcell-monitor/keys")


def _add_zenoh_args(p: argparse.ArgumentParser, default_mode: str = "peer",
                    listen_flag: str = "--listen", default_connect: bool = False) -> None:
    g = p.add_argument_group("Zenoh")
    g.add_argument("--cell", default="cell1",
                   help="cell name; keys are workcell/<cell>/... (default cell1)")
    g.add_argument("--prefix", help="key prefix (default workcell/<cell>/)")
    g.add_argument("--mode", choices=MODES, default=None,
                   help=f"session mode (default {default_mode}, or the --zenoh-config file's)")
    connect_default = (f"{DEFAULT_CONNECT}, where a default `monitor run` listens, unless "
                       f"{listen_flag} or --zenoh-config is given" if default_connect else "none")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help=f"endpoint to connect to, e.g. tcp/10.0.0.5:7447 (repeatable; default "
                   f"{connect_default})")
    g.add_argument(listen_flag, dest="zlisten", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable; default "
                   "none)")
    g.add_argument("--zenoh-config", help="Zenoh JSON5 config file used as the base (default "
                   "none)")
    g.add_argument("--scouting", action="store_true",
                   help="enable multicast scouting (default off)")
    g.add_argument("--tls-ca", help="CA certificate (PEM) for tls/ endpoints (default none)")
    g.add_argument("--tls-cert", help="this side's certificate (PEM) (default none)")
    g.add_argument("--tls-key", help="this side's private key (PEM) (default none)")
    g.add_argument("--user", help="Zenoh user name; password from --password-file "
                   "(default none)")
    g.add_argument("--password-file", help="file whose first line is the Zenoh password "
                   "(default none)")
    g.add_argument("--instance", help="instance id (default <command>-<host>-<pid>-<random>)")
    p.set_defaults(default_mode=default_mode, default_connect=default_connect)


def _bus_config(args: argparse.Namespace, **over) -> BusConfig:
    password = None
    if args.password_file:
        try:
            with open(args.password_file, encoding="utf-8") as fh:
                password = fh.readline().rstrip("\n")
        except OSError as exc:
            raise ConfigError(f"{args.password_file}: cannot read the password: "
                              f"{exc.strerror}") from None
    connect = tuple(args.connect)
    if not connect and not args.zlisten and not args.zenoh_config and args.default_connect:
        connect = (DEFAULT_CONNECT,)
    kw = dict(
        cell=args.cell, prefix=args.prefix,
        mode=args.mode or (None if args.zenoh_config else args.default_mode),
        listen=tuple(args.zlisten), connect=connect,
        multicast_scouting=args.scouting, zenoh_config_file=args.zenoh_config,
        tls_root_ca=args.tls_ca, tls_cert=args.tls_cert, tls_key=args.tls_key,
        user=args.user, password=password,
    )
    if getattr(args, "instance", None):
        kw["instance"] = args.instance
    kw.update(over)
    return BusConfig(**kw)


def _where(bus: BusConfig) -> str:
    """Where a command looked, for 'found nothing' messages."""
    ends = [*bus.connect, *(f"listen {e}" for e in bus.listen)] or [
        f"the --zenoh-config file {bus.zenoh_config_file}"]
    return ", ".join(ends)


def _nothing_found_hint(bus: BusConfig) -> str:
    return (f"looked via {_where(bus)} on cell {bus.cell!r}; is `monitor run` up? try "
            f"--connect tcp/<monitor host>:7447 and --cell <name> (see `monitor status --help`)")


# --- watch -----------------------------------------------------------------------------------


def _fmt_time() -> str:
    t = time.time()
    return time.strftime("%H:%M:%S", time.localtime(t)) + f".{int(t * 1000) % 1000:03d}"


def _reasons_text(command: dict | None) -> str:
    if not command:
        return ""
    reasons = command.get("reasons")
    if not isinstance(reasons, list):
        return ""
    return "; ".join(str(r.get("message", r.get("code", ""))) for r in reasons
                     if isinstance(r, dict))


def _latch_text(command: dict | None) -> str:
    """The latched state as the monitor reports it (h4's fields when present)."""
    if not command or not command.get("latched"):
        return ""
    by = command.get("latched_by")
    text = "LATCHED"
    if isinstance(by, dict) and by.get("message"):
        text += f" by {by['message']}"
    clear = command.get("clear_for_s")
    if isinstance(clear, int | float) and not isinstance(clear, bool):
        text += f"; cell clear for {clear:.1f} s"
    possible = command.get("reset_possible")
    if possible is True:
        text += ": reset possible (`monitor reset --operator <id>`)"
    elif possible is False:
        text += ": reset not possible yet"
    return text


def _emit(args, event: dict, text: str) -> None:
    if args.json:
        print(json.dumps(event, default=str), flush=True)
    else:
        print(f"{_fmt_time()} {text}", flush=True)


def _watchdog(args: argparse.Namespace, bus: BusConfig, keys: BusKeys
              ) -> CommandWatchdog | CellWatchdog:
    public_keys = tuple(load_public_key(p) for p in args.monitor_key)
    if getattr(args, "expect", None):  # several monitors on the cell (docs/consumer.md)
        return _cell_watchdog(args, bus, public_keys)
    try:
        return CommandWatchdog(max_ttl_ms=args.ttl_ms, instance=args.follow,
                               require_liveliness=not args.no_liveliness,
                               public_keys=public_keys,
                               cell=bus.cell if bus.prefix is None else None,
                               key_expr=keys.command, clock_sync_ms=args.clock_sync_ms)
    except ValueError as exc:  # --ttl-ms / --clock-sync-ms out of range
        raise ConfigError(f"monitor watch: {exc}") from None


def _cell_watchdog(args: argparse.Namespace, bus: BusConfig, public_keys: tuple
                   ) -> CellWatchdog:
    if public_keys or args.follow:
        raise ConfigError("--expect ROLE=KEYFILE names every monitor and its key: use it "
                          "instead of --monitor-key and --follow")
    try:
        expected = parse_expect(args.expect, load_public_key)
        return CellWatchdog(expected, bus.key_prefix, max_ttl_ms=args.ttl_ms,
                            require_liveliness=not args.no_liveliness,
                            cell=bus.cell if bus.prefix is None else None,
                            clock_sync_ms=args.clock_sync_ms)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def add_expect_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--expect", action="append", default=[], metavar="ROLE=KEYFILE",
                   help="a monitor of this cell by its [bus] role and its public key file "
                   "(repeatable: every monitor of the cell; the cell RUNs only when all say "
                   "RUN, an unexpected one is STOP; docs/consumer.md; default: one monitor, "
                   "--monitor-key)")


def cmd_watch(args: argparse.Namespace) -> int:
    with StopSignals(name="monitor watch") as stop:
        bus = _bus_config(args, instance=args.instance or default_instance("watch"))
        keys = BusKeys.of(bus.key_prefix)
        dog = _watchdog(args, bus, keys)
        if args.inbox < 1:
            raise ConfigError(f"--inbox {args.inbox}: must be at least 1")
        inbox = Inbox(args.inbox)
        clock = time.monotonic
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 0
        if not dog.public_keys:
            print("monitor watch: no --monitor-key given: commands are NOT authenticated "
                  "(anyone on the bus can forge RUN)", file=sys.stderr, flush=True)
        entities = []
        try:
            entities = (subscribe_cell(session, bus.key_prefix, inbox, clock)
                        if isinstance(dog, CellWatchdog) else
                        _watch_subscriptions(session, keys, inbox, clock))
            _watch_loop(args, dog, inbox, stop, clock)
        finally:
            if not close_bounded(session, 1.0, entities):
                print("monitor watch: Zenoh did not close within 1 s; exiting anyway",
                      file=sys.stderr, flush=True)
        return exit_if_stopped(stop)


def _watch_subscriptions(session, keys: BusKeys, inbox, clock) -> list:
    def attachment(s) -> bytes | None:
        return s.attachment.to_bytes() if s.attachment is not None else None

    def put(kind: str, *item) -> None:
        inbox.put(kind, (kind, *item))

    return [
        session.declare_subscriber(keys.command, lambda s: put(
            "command", s.payload.to_bytes(), attachment(s), clock(), time.time())),
        session.declare_subscriber(keys.alert, lambda s: put(
            "alert", s.payload.to_bytes(), attachment(s), clock())),
        session.liveliness().declare_subscriber(keys.alive + "/*", lambda s: put(
            "alive", str(s.key_expr), s.kind == zenoh.SampleKind.PUT, clock()), history=True),
    ]


def _watch_loop(args, dog: CommandWatchdog, inbox, stop, clock) -> None:
    end = clock() + args.duration if args.duration else None
    shown: tuple | None = None
    shown_at = clock()
    last_summary = clock()
    rejected_shown: dict[str, float] = {}
    accepted = 0
    while not stop.is_set() and (end is None or clock() < end):
        entry = inbox.get(timeout=args.tick)
        kind = None
        if entry is not None:
            kind, payload, extra, t_recv, *wall_recv = entry
        if kind == "command":
            # both clocks read on arrival: waiting in the inbox is no reason to drop a command
            # wall_recv: the wall clock on arrival (and the key, from subscribe_cell)
            why = dog.on_command(payload, t_recv, extra, *wall_recv)
            accepted += why is None
            # every rejection code is shown at most once a second (a flood is counted)
            loud = why and t_recv - rejected_shown.get(why, -1e9) >= 1.0
            if args.verbose or loud:
                if loud:
                    rejected_shown[why] = t_recv
                body = _safe_json(payload)
                _emit(args, {"event": "command", "mono": t_recv, "rejected": why,
                             "detail": dog.last_rejection if why else "", "body": body},
                      (f"REJECTED command ({dog.last_rejection}); "
                       f"{sum(dog.rejected.values())} rejected so far" if why else
                       f"command seq={body.get('seq')} {body.get('state')} "
                       f"{_reasons_text(body)}"))
        elif kind == "alert":
            body = _safe_json(payload)
            _emit(args, {"event": "alert", "mono": t_recv, "body": body,
                         "snapshot_bytes": len(extra) if extra else 0},
                  f"ALERT {str(body.get('severity', '?')).upper()} {body.get('kind')} "
                  f"from {body.get('source')}: {body.get('message')}"
                  + (f" (+{body['repeat']} repeats)" if body.get("repeat") else "")
                  + (f" [snapshot {len(extra)} B]" if extra else ""))
        elif kind == "alive":
            dog.on_liveliness(payload, bool(extra))
            _emit(args, {"event": "liveliness", "mono": t_recv, "key": payload,
                         "alive": bool(extra)},
                  f"liveliness {payload} {'appeared' if extra else 'VANISHED'}")
        now = clock()
        verdict = dog.verdict(now)
        cmd = verdict.command or {}
        codes = tuple(str(r.get("code")) for r in cmd.get("reasons", []) if isinstance(r, dict)
                      ) if not verdict.code else ()
        key = (verdict.state, verdict.speed_scale, verdict.code, codes, bool(cmd.get("latched")),
               cmd.get("reset_possible"))
        if key != shown:
            shown, shown_at, last_summary = key, now, now
            _emit_verdict(args, verdict, now)
        elif args.every > 0 and now - last_summary >= args.every:
            last_summary = now
            _emit(args, {"event": "steady", "mono": now, "state": verdict.state,
                         "for_s": now - shown_at, "seq": verdict.seq, "accepted": accepted,
                         "rejected": dict(dog.rejected), "inbox_dropped": dict(inbox.dropped)},
                  f"  ... {verdict.state} for {now - shown_at:.0f} s (seq {verdict.seq}, "
                  f"{accepted} commands, {sum(dog.rejected.values())} rejected"
                  + (f", {sum(inbox.dropped.values())} dropped unread (flood)"
                     if inbox.dropped else "") + ")")


def _emit_verdict(args, v: Verdict, now: float) -> None:
    why = v.reason or _reasons_text(v.command) or ("all clear" if v.state == "RUN" else "")
    latch = _latch_text(v.command) if not v.code else ""
    inst = (v.command or {}).get("instance", "")
    _emit(args, {"event": "verdict", "mono": now, "state": v.state, "speed_scale": v.speed_scale,
                 "code": v.code, "reason": v.reason, "seq": v.seq, "command": v.command},
          f"{v.state:<4} scale={v.speed_scale:.2f} seq={v.seq} [{inst}] {why}"
          + (f" | {latch}" if latch else ""))


def _safe_json(payload: bytes) -> dict:
    try:
        body = json.loads(payload)
        return body if isinstance(body, dict) else {"value": body}
    except (ValueError, UnicodeDecodeError, RecursionError):
        return {"invalid": payload[:200].hex()}


# --- bridge otus -----------------------------------------------------------------------------


def cmd_bridge_otus(args: argparse.Namespace) -> int:
    with StopSignals(name="monitor bridge otus") as stop:
        return _bridge_otus(args, stop)


def _bridge_otus(args: argparse.Namespace, stop) -> int:
    host, port = parse_host_port(args.udp_listen)
    bus = _bus_config(args, instance=args.instance or default_instance("otus-bridge"))
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
    try:
        session = call_interruptible(lambda: open_session(bus), stop)
    except Interrupted:
        sock.close()
        return 0
    with sock, _bounded(session, "monitor bridge otus") as session:
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
    return exit_if_stopped(stop)


class _bounded:
    """``with _bounded(session):`` closes the session with a deadline (``close_bounded``)."""

    def __init__(self, session, name: str, undeclare: list | None = None) -> None:
        self.session, self.name = session, name
        self.undeclare = undeclare if undeclare is not None else []

    def __enter__(self):
        return self.session

    def __exit__(self, *exc) -> None:
        if not close_bounded(self.session, 1.0, self.undeclare):
            print(f"{self.name}: Zenoh did not close within 1 s; exiting anyway",
                  file=sys.stderr, flush=True)


# --- router, reset, status, keys ------------------------------------------------------------


def cmd_router(args: argparse.Namespace) -> int:
    with StopSignals(name="monitor router") as stop:
        bus = _bus_config(args, instance=args.instance or default_instance("router"))
        if not bus.listen and not args.zenoh_config:
            raise ConfigError("monitor router: give --listen ENDPOINT (e.g. tcp/127.0.0.1:7447;"
                              " tcp/0.0.0.0:7447 opens it to the network) or --zenoh-config")
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 0
        with _bounded(session, "monitor router") as session:
            print(f"monitor router: zid {session.zid()} listening on {list(bus.listen)}",
                  file=sys.stderr, flush=True)
            wait_for_stop(stop)
        return exit_if_stopped(stop)


def _operator_key_path(args: argparse.Namespace) -> Path | None:
    if args.key:
        return Path(args.key)
    default = (KEY_DIR / f"{args.operator}.key").expanduser()
    return default if default.exists() else None


def cmd_reset(args: argparse.Namespace) -> int:
    """Exit 0 when the monitor accepted the reset, 1 when it refused (reason printed), 2 when
    nothing answered."""
    with StopSignals(name="monitor reset") as stop:
        bus = _bus_config(args, instance=args.instance or default_instance("reset"))
        keys = BusKeys.of(bus.key_prefix)
        key_path = _operator_key_path(args)
        signer = load_private_key(key_path) if key_path else None
        if signer is None:
            print(f"monitor reset: no key for {args.operator} (--key, or "
                  f"{KEY_DIR}/{args.operator}.key): sending unsigned; a monitor with "
                  "operators configured refuses it", file=sys.stderr, flush=True)
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 130
        with _bounded(session, "monitor reset") as session:
            if args.role:  # several monitors on the cell: each latched one (cell_reset.py)
                from monitor.cli.cell_reset import reset_roles

                return reset_roles(args, bus, session, signer, stop, _first_status)
            started = time.monotonic()
            answer = None
            # the reset names the monitor's boot and the latch it releases (signed into it)
            status = _first_status(session, keys, args.timeout, stop)
            if status is None:
                if stop.is_set():
                    return 130
                raise ConfigError(f"monitor reset: no monitor answered on {keys.status} within "
                                  f"{args.timeout:g} s; {_nothing_found_hint(bus)}")
            boot, latch = latch_of_status(status)
            if latch is None:
                print(f"monitor reset: nothing to reset: the monitor is not latched (state "
                      f"{status.get('state')}, no latch nonce in its status)")
                return 1
            payload = reset_payload(args.operator, args.request_id, args.note,
                                    cell=bus.cell if bus.prefix is None else "",
                                    confirm_clear=args.confirm_clear, boot=boot, latch=latch)
            signature = signer.sign(keys.reset, payload) if signer else None
            if args.confirm_clear:
                print(f"monitor reset: {args.operator} confirms having looked: the cell is "
                      "clear (logged and alerted by the monitor)", file=sys.stderr, flush=True)
            while answer is None and not stop.is_set():
                left = args.timeout - (time.monotonic() - started)
                if left <= 0:
                    break
                asked = time.monotonic()
                try:
                    answer = call_interruptible(lambda left=left: request_reset(
                        session, keys.reset, payload, signature, left), stop)
                except Interrupted:
                    break
                if answer is not None or time.monotonic() - asked > 0.2:
                    break  # answered, or a monitor got it and did not answer in time
                stop.wait(0.1)  # nothing routed yet (session still connecting): ask again
        if stop.is_set():
            return 130
    if answer is None:
        raise ConfigError(f"monitor reset: no monitor answered on {keys.reset} within "
                          f"{args.timeout:g} s; {_nothing_found_hint(bus)}")
    verdict = "accepted" if answer["accepted"] else "REFUSED"
    print(f"reset by {args.operator} {verdict}: {answer.get('reason', '')}"
          + (f" (monitor now {answer['state']})" if answer.get("state") else ""))
    return 0 if answer["accepted"] else 1


def _first_status(session, keys: BusKeys, timeout: float, stop) -> dict | None:
    """The first status answer (a JSON object) within ``timeout``; None when none came."""
    started = time.monotonic()
    while not stop.is_set():
        left = timeout - (time.monotonic() - started)
        if left <= 0:
            return None
        try:
            replies = call_interruptible(lambda left=left: [
                r.ok.payload.to_bytes() for r in session.get(keys.status, timeout=left)
                if r.ok is not None], stop)
        except Interrupted:
            return None
        for payload in replies:
            body = _safe_json(payload)
            if isinstance(body.get("boot"), str):
                return body
        stop.wait(min(0.2, max(0.0, left)))  # nothing routed yet: ask again
    return None


def cmd_status(args: argparse.Namespace) -> int:
    with StopSignals(name="monitor status") as stop:
        bus = _bus_config(args, instance=args.instance or default_instance("status"))
        keys = BusKeys.of(bus.key_prefix)
        answers = 0
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 130
        started = time.monotonic()
        with _bounded(session, "monitor status") as session:
            while not answers and not stop.is_set():
                left = args.timeout - (time.monotonic() - started)
                if left <= 0:
                    break
                try:
                    replies = call_interruptible(lambda left=left: [
                        r.ok.payload.to_bytes() for r in session.get(keys.status, timeout=left)
                        if r.ok is not None], stop)
                except Interrupted:
                    break
                for payload in replies:
                    answers += 1
                    print(json.dumps(json.loads(payload), indent=2))
                if not answers:
                    stop.wait(min(0.2, max(0.0, left)))  # nothing routed yet: ask again
        waited = time.monotonic() - started
    if stop.is_set():
        return 130
    if not answers:
        raise ConfigError(f"monitor status: no answer on {keys.status} within {waited:.1f} s; "
                          f"{_nothing_found_hint(bus)}")
    return 0


def cmd_keys_new(args: argparse.Namespace) -> int:
    if args.path:
        path = Path(args.path)
    elif args.operator:
        path = (KEY_DIR / f"{args.operator}.key").expanduser()
    else:
        raise ConfigError("monitor keys new: give a PATH for the key, or --operator NAME "
                          f"(then {KEY_DIR}/NAME.key)")
    if args.operator and any(c.isspace() or c == "#" for c in args.operator):
        raise ConfigError(f"--operator {args.operator!r}: no spaces or '#' in operator ids")
    private, public, text = new_key_pair(path, force=args.force)
    print(f"private key: {private} (mode 600; keep it on this host only)")
    print(f"public key:  {public}")
    print(text)
    if args.operator:
        print(f"add this line to the monitor's operators file (bus.operators_file):\n"
              f"{args.operator} {text}")
    else:
        print("monitor: set bus.signing_key to the private key; give consumers the public key "
              "(`monitor watch --monitor-key " + str(public) + "`)")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("watch", help="print commands and alerts; apply the consumer rule",
                              description="Reference consumer: reports STOP when no valid "
                              "command arrived within ttl, when seq goes backwards, when the "
                              "monitor's liveliness token vanishes or when two monitors are "
                              "live. Prints state changes with reasons and a steady-state line.")
    _add_zenoh_args(p, default_connect=True)
    p.add_argument("--monitor-key", action="append", default=[], metavar="FILE",
                   help="the monitor's public key file (ed25519:...); only commands signed by "
                   "it count (repeatable; default none: unauthenticated, with a warning)")
    p.add_argument("--ttl-ms", type=float, default=1000.0,
                   help="this consumer's cap on every command's ttl_ms (default 1000)")
    p.add_argument("--clock-sync-ms", type=float, default=DEFAULT_CLOCK_SYNC_MS,
                   help="how closely this host's clock agrees with the monitor's, as your "
                   "deployment guarantees (one host, NTP/PTP); a command arriving later than "
                   "this + its ttl after its signed wall time is dropped (default "
                   f"{DEFAULT_CLOCK_SYNC_MS:g})")
    p.add_argument("--follow", metavar="INSTANCE",
                   help="only accept this monitor instance (default: any, one at a time)")
    add_expect_arg(p)
    p.add_argument("--no-liveliness", action="store_true",
                   help="do not require the liveliness token (not recommended; default off)")
    p.add_argument("--json", action="store_true",
                   help="one JSON object per line (default: text)")
    p.add_argument("--verbose", "-v", action="store_true",
                   help="print every command (default: only changes and a steady line)")
    p.add_argument("--every", type=float, default=10.0,
                   help="s between steady-state lines while nothing changes (default 10; 0 off)")
    p.add_argument("--duration", type=float, default=None,
                   help="exit after this many seconds (default: run until SIGINT/SIGTERM)")
    p.add_argument("--inbox", type=int, default=DEFAULT_BOUND, metavar="N",
                   help="messages of each kind held while this consumer is busy; when full the "
                   f"oldest is dropped and counted (default {DEFAULT_BOUND})")
    p.add_argument("--tick", type=float, default=0.01, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_watch)

    bridge = subparsers.add_parser("bridge", help="bridge external streams onto the bus")
    bsub = bridge.add_subparsers(dest="bridge_kind", metavar="KIND", required=True)
    p = bsub.add_parser("otus", help="republish OTUS tracker UDP packets as pose samples")
    p.add_argument("--listen", dest="udp_listen", default="127.0.0.1:5400", metavar="HOST:PORT",
                   help="UDP address to receive OTUS packets on (default 127.0.0.1:5400)")
    _add_zenoh_args(p, listen_flag="--zenoh-listen")
    p.add_argument("--max-speed", type=float, default=PoseLimits.max_speed_m_s,
                   help=f"m/s, plausibility limit (default {PoseLimits.max_speed_m_s:g})")
    p.add_argument("--max-accel", type=float, default=PoseLimits.max_accel_m_s2,
                   help=f"m/s², plausibility limit (default {PoseLimits.max_accel_m_s2:g})")
    p.add_argument("--quaternion-tolerance", type=float,
                   default=PoseLimits.quaternion_tolerance,
                   help="allowed deviation of |q| from 1 (default "
                   f"{PoseLimits.quaternion_tolerance:g})")
    p.add_argument("--pose-timeout", type=float, default=0.1,
                   help="s of UDP silence that raise a pose_silence alert (once per gap; "
                   "default 0.1)")
    p.add_argument("--alert-interval", type=float, default=5.0,
                   help="s between two pose_rejected alerts (repeats are counted; default 5)")
    p.set_defaults(func=cmd_bridge_otus)
    from monitor.cli.adapters import register_bridges  # robot-side outputs (docs/adapters.md)

    register_bridges(bsub, _add_zenoh_args)

    p = subparsers.add_parser("router", help="run a Zenoh router until SIGINT/SIGTERM")
    _add_zenoh_args(p, default_mode="router")
    p.set_defaults(func=cmd_router)

    p = subparsers.add_parser(
        "reset", help="ask the monitor to release a latched STOP; waits for its answer",
        description="Sends a reset request signed with the operator's key and prints the "
        "monitor's answer. Exit 0 accepted, 1 refused (reason printed), 2 no answer.")
    _add_zenoh_args(p, default_connect=True)
    p.add_argument("--operator", required=True, help="operator id, as in the monitor's "
                   "operators file (required)")
    p.add_argument("--key", metavar="FILE", help="the operator's private key (default "
                   f"{KEY_DIR}/<operator>.key when it exists)")
    p.add_argument("--confirm-clear", action="store_true",
                   help="I have looked: the cell is clear; lets the monitor drop holds of "
                   "persons lost inside a zone (never of persons seen); logged and alerted "
                   "(default off)")
    p.add_argument("--request-id", default="",
                   help="unique id of this request (default <operator>-<time>-<random>)")
    p.add_argument("--note", default="", help="free text for the log (default empty)")
    p.add_argument("--timeout", type=float, default=3.0,
                   help="s to wait for the monitor's answer (default 3)")
    p.add_argument("--role", action="append", default=[], metavar="ROLE",
                   help="a monitor of the cell by its [bus] role (repeatable: name every "
                   "monitor of the cell); each latched one gets its own signed request and "
                   "answers; exit 0 only when all accepted (default: the cell's only monitor)")
    p.set_defaults(func=cmd_reset)

    p = subparsers.add_parser("status", help="query the monitor's status")
    _add_zenoh_args(p, default_connect=True)
    p.add_argument("--timeout", type=float, default=3.0,
                   help="s to wait for an answer (default 3)")
    p.set_defaults(func=cmd_status)

    keys = subparsers.add_parser("keys", help="make signing keys (monitor, operators)")
    ksub = keys.add_subparsers(dest="keys_action", metavar="ACTION", required=True)
    p = ksub.add_parser("new", help="write a new Ed25519 key pair (private key mode 600)",
                        description="Writes PATH (private, mode 600) and PATH.pub (public). "
                        "Never overwrites an existing key unless --force.")
    p.add_argument("path", nargs="?", help="private key file to write (default "
                   f"{KEY_DIR}/<operator>.key with --operator)")
    p.add_argument("--operator", help="operator id: print the line for the operators file "
                   "(default: a monitor key)")
    p.add_argument("--force", action="store_true",
                   help="replace existing key files (default: refuse)")
    p.set_defaults(func=cmd_keys_new)
