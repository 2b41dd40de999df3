"""``monitor watch``: the reference consumer; prints commands, alerts and the consumer rule's
verdict. Stops within 2 s of SIGINT/SIGTERM in every phase (``monitor.signals``)."""

from __future__ import annotations

import argparse
import json
import sys
import time

from monitor.adapters.follower import subscribe
from monitor.bus.session import (
    BusConfig,
    BusKeys,
    CommandWatchdog,
    Verdict,
    default_instance,
    open_session,
)
from monitor.cli.zenoh_args import add_zenoh_args, bus_config, nothing_found_hint, safe_json
from monitor.errors import ConfigError
from monitor.signals import (
    Interrupted,
    StopSignals,
    call_interruptible,
    close_bounded,
    exit_if_stopped,
)
from monitor.wire.cell_consumer import CellWatchdog, parse_expect, subscribe_cell
from monitor.wire.consumer import DEFAULT_CLOCK_SYNC_MS
from monitor.wire.inbox import DEFAULT_BOUND, Inbox
from monitor.wire.signing import load_public_key

HINT_AFTER_S = 3.0  # s of silence before watch says where it looked and what to try


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


def make_watchdog(args: argparse.Namespace, bus: BusConfig, keys: BusKeys
                  ) -> CommandWatchdog | CellWatchdog:
    """The consumer rule from the watch options (shared by bridges and the console)."""
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
        bus = bus_config(args, instance=args.instance or default_instance("watch"))
        keys = BusKeys.of(bus.key_prefix)
        dog = make_watchdog(args, bus, keys)
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
            _watch_loop(args, dog, inbox, stop, clock, nothing_found_hint(bus))
        finally:
            if not close_bounded(session, 1.0, entities):
                print("monitor watch: Zenoh did not close within 1 s; exiting anyway",
                      file=sys.stderr, flush=True)
        return exit_if_stopped(stop)


def _watch_subscriptions(session, keys: BusKeys, inbox, clock) -> list:
    """What the reference consumer listens to: the adapters' own subscriptions (one code)."""
    return subscribe(session, keys, inbox, clock)


def _watch_loop(args, dog: CommandWatchdog, inbox, stop, clock, hint: str) -> None:
    end = clock() + args.duration if args.duration else None
    heard = clock()  # when the last message of any kind arrived (start: none yet)
    hinted = False
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
            heard, hinted = t_recv, False
        elif not hinted and clock() - heard >= args.hint_after:
            # silence says STOP below; this says where we looked and what to try
            hinted = True
            print(f"monitor watch: nothing heard for {args.hint_after:g} s (no command, alert "
                  f"or liveliness token); {hint}", file=sys.stderr, flush=True)
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
                body = safe_json(payload)
                _emit(args, {"event": "command", "mono": t_recv, "rejected": why,
                             "detail": dog.last_rejection if why else "", "body": body},
                      (f"REJECTED command ({dog.last_rejection}); "
                       f"{sum(dog.rejected.values())} rejected so far" if why else
                       f"command seq={body.get('seq')} {body.get('state')} "
                       f"{_reasons_text(body)}"))
        elif kind == "alert":
            body = safe_json(payload)
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


def register(subparsers) -> None:
    p = subparsers.add_parser("watch", help="print commands and alerts; apply the consumer rule",
                              description="Reference consumer: reports STOP when no valid "
                              "command arrived within ttl, when seq goes backwards, when the "
                              "monitor's liveliness token vanishes or when two monitors are "
                              "live. Prints state changes with reasons and a steady-state line.")
    add_zenoh_args(p, default_connect=True)
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
    p.add_argument("--hint-after", type=float, default=HINT_AFTER_S, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_watch)
