"""Operator commands: ``monitor reset`` (release a latched STOP) and ``monitor status``."""

from __future__ import annotations

import argparse
import json
import queue
import sys
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from monitor.bus.session import BusKeys, default_instance, open_session
from monitor.cli.keys import KEY_DIR
from monitor.cli.monitor_key_arg import add_monitor_key_arg, monitor_keys_of
from monitor.cli.role_arg import add_role_arg
from monitor.cli.roles import no_answer, role_keys
from monitor.cli.status_text import status_text
from monitor.cli.zenoh_args import (
    add_zenoh_args,
    bounded,
    bus_config,
    nothing_found_hint,
    safe_json,
)
from monitor.errors import ConfigError
from monitor.signals import Interrupted, StopSignals, call_interruptible
from monitor.wire.answers import ignored_text, reply_of, status_request
from monitor.wire.resets import latch_of_status, request_reset, reset_payload
from monitor.wire.signing import load_private_key, load_public_key

STATUS_GRACE_S = 0.2  # s to wait for more monitors' status after the first
_END = object()  # put by the query's drop callback: no more replies will come


def operator_key_path(args: argparse.Namespace) -> Path | None:
    if args.key:
        return Path(args.key)
    default = (KEY_DIR / f"{args.operator}.key").expanduser()
    return default if default.exists() else None


def cmd_reset(args: argparse.Namespace) -> int:
    """Exit 0 when the monitor accepted the reset, 1 when it refused (reason printed), 2 when
    nothing answered."""
    with StopSignals(name="monitor reset") as stop:
        bus = bus_config(args, instance=args.instance or default_instance("reset"))
        keys = role_keys(bus)
        key_path = operator_key_path(args)
        signer = load_private_key(key_path) if key_path else None
        monitor_keys = (tuple(load_public_key(k) for k in args.monitor_key)
                        if args.monitor_key else None)
        if monitor_keys is None:
            print("monitor reset: no --monitor-key: the answer is NOT authenticated (anyone "
                  "who may answer on the reset key could have sent it)", file=sys.stderr,
                  flush=True)
        if signer is None:
            print(f"monitor reset: no key for {args.operator} (--key, or "
                  f"{KEY_DIR}/{args.operator}.key): sending unsigned; a monitor with "
                  "operators configured refuses it", file=sys.stderr, flush=True)
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 130
        with bounded(session, "monitor reset") as session:
            if args.role:  # several monitors on the cell: each latched one (cell_reset.py)
                from monitor.cli.cell_reset import reset_roles

                return reset_roles(args, bus, session, signer, stop, first_status,
                                   monitor_keys)
            started = time.monotonic()
            answer = None
            # the reset names the monitor's boot and the latch it releases (signed into it)
            skipped: list[str] = []  # status answers not the monitor's (--monitor-key)
            status = first_status(session, keys, args.timeout, stop, monitor_keys, skipped)
            if (line := status_ignored_line("monitor reset", keys.status, skipped)):
                print(line, file=sys.stderr, flush=True)
            if status is None:
                if stop.is_set():
                    return 130
                raise no_answer("monitor reset", keys.status, args.timeout, bus, session, stop)
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
            ignored: list[str] = []  # answers not believed (--monitor-key): someone else's
            while answer is None and not stop.is_set():
                left = args.timeout - (time.monotonic() - started)
                if left <= 0:
                    break
                asked = time.monotonic()
                try:
                    answer = call_interruptible(lambda left=left: request_reset(
                        session, keys.reset, payload, signature, left, monitor_keys, ignored),
                        stop)
                except Interrupted:
                    break
                if answer is not None or time.monotonic() - asked > 0.2:
                    break  # answered, or a monitor got it and did not answer in time
                stop.wait(0.1)  # nothing routed yet (session still connecting): ask again
        if stop.is_set():
            return 130
    if answer is None:
        signed = " with an answer signed by --monitor-key" if monitor_keys else ""
        raise ConfigError(f"monitor reset: no monitor answered{signed} on {keys.reset} within "
                          f"{args.timeout:g} s"
                          + (f"; {ignored_text(ignored)}: someone else answers there"
                             if ignored else "") + f"; {nothing_found_hint(bus)}")
    if ignored:
        print(f"monitor reset: {ignored_text(ignored)}: someone else answers on {keys.reset}",
              file=sys.stderr, flush=True)
    verdict = "accepted" if answer["accepted"] else "REFUSED"
    print(f"reset by {args.operator} {verdict}: {answer.get('reason', '')}"
          + (f" (monitor now {answer['state']})" if answer.get("state") else ""))
    print(f"answered by {answered_by(answer)}")
    return 0 if answer["accepted"] else 1


def answered_by(answer: dict) -> str:
    """Which monitor answered: its instance and boot, and the key that signed it (or not)."""
    who = f"monitor {answer.get('instance', '?')} (boot {str(answer.get('boot', '?'))[:8]})"
    key = answer.get("signed_by")
    return f"{who}, signed by {key}" if key else f"{who}, NOT authenticated"


def ask(session, key: str, timeout: float, stop, want: Callable[[bytes], dict | None],
        grace: float = 0.0, monitor_keys: tuple | None = None,
        ignored: list[str] | None = None) -> list[dict]:
    """The answers on ``key`` that ``want`` accepts (it returns None for the others), returned
    at the first one: only those arriving within ``grace`` s after it are added (a second
    monitor on the cell). It never waits for the query itself to end: a queryable that never
    finishes its answer (a hung peer) would hold the command until ``timeout``. A query that
    ends unanswered (nothing routed yet: the session is still connecting) is asked again until
    ``timeout``. Returns [] when nothing answered or ``stop`` was set. ``monitor_keys``: the
    query carries a fresh nonce (``status_request``) and only answers signed by one of the
    keys naming it count (``signed_by`` set); why each other one was skipped is appended to
    ``ignored``."""
    started = time.monotonic()
    answers: list[dict] = []
    first_at: float | None = None
    while not stop.is_set() and not answers:
        left = timeout - (time.monotonic() - started)
        if left <= 0:
            break
        inbox: queue.SimpleQueue = queue.SimpleQueue()
        request = status_request() if monitor_keys is not None else None
        # no consolidation: Zenoh's default keeps every reply until all queryables finished
        session.get(key, handler=zenoh.handlers.Callback(inbox.put, lambda q=inbox: q.put(_END)),
                    consolidation=zenoh.ConsolidationMode.NONE, timeout=left, payload=request)
        while not stop.is_set():
            until = started + timeout if first_at is None else first_at + grace
            wait = until - time.monotonic()
            if wait <= 0:
                return answers
            try:  # in slices: the stop signal is seen within 50 ms
                reply = inbox.get(timeout=min(0.05, wait))
            except queue.Empty:
                continue
            if reply is _END:
                break  # the query ended: with answers, done; without, ask again
            counted = reply_of(reply, key, request, monitor_keys, ignored)
            if counted is None:
                continue
            raw, signer = counted
            body = want(raw)
            if body is not None and signer is not None:
                body = {**body, "signed_by": signer}
            if body is not None:
                answers.append(body)
                first_at = first_at if first_at is not None else time.monotonic()
        if not answers:
            stop.wait(min(0.1, max(0.0, left)))
    return answers


def _monitor_status(payload: bytes) -> dict | None:
    body = safe_json(payload)
    return body if isinstance(body.get("boot"), str) else None


def first_status(session, keys: BusKeys, timeout: float, stop,
                 monitor_keys: tuple | None = None,
                 ignored: list[str] | None = None) -> dict | None:
    """The first status answer of a monitor within ``timeout``; None when none came.
    ``monitor_keys``: only the monitor's answer signed for this query counts (what a request
    then names, its boot and latch, is the monitor's, not a rogue's on the status key); why
    each other answer was skipped is appended to ``ignored``."""
    answers = ask(session, keys.status, timeout, stop, _monitor_status,
                  monitor_keys=monitor_keys, ignored=ignored)
    return answers[0] if answers else None


def status_ignored_line(command: str, key: str, ignored: list[str]) -> str | None:
    """``monitor reset: 2 answers ignored (2 unsigned) on the status key ...``: the status
    answers that were not the monitor's (None when there were none)."""
    if not ignored:
        return None
    return f"{command}: {ignored_text(ignored)} on {key}: someone else answers there"


def cmd_status(args: argparse.Namespace) -> int:
    with StopSignals(name="monitor status") as stop:
        bus = bus_config(args, instance=args.instance or default_instance("status"))
        monitor_keys = monitor_keys_of(args, "monitor status")
        roles = list(dict.fromkeys(args.role)) or [""]
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 130
        answered: list[tuple[str, BusKeys, list[dict], float]] = []
        ignored: list[str] = []  # answers not believed (--monitor-key): someone else's
        with bounded(session, "monitor status") as session:
            for role in roles:
                keys = role_keys(bus, role)
                started = time.monotonic()
                # every monitor that answers within STATUS_GRACE_S of the first is shown (two
                # monitors on one cell, or of one role, is a fault the operator must see)
                answers = ask(session, keys.status, args.timeout, stop, _any_json,
                              STATUS_GRACE_S, monitor_keys, ignored)
                answered.append((role, keys, answers, time.monotonic() - started))
                if stop.is_set():
                    return 130
            if roles == [""] and not answers:
                if ignored:
                    print(f"monitor status: {ignored_text(ignored)}: someone else answers on "
                          f"{keys.status}", file=sys.stderr, flush=True)
                raise no_answer("monitor status", keys.status, args.timeout, bus, session,
                                stop)
    if ignored:
        print(f"monitor status: {ignored_text(ignored)}: someone else answers on the status "
              "key", file=sys.stderr, flush=True)
    silent = 0
    for role, keys, answers, waited in answered:
        if role and not answers:
            silent += 1
            print(f"{role}: NO ANSWER on {keys.status} within {waited:.1f} s")
        for body in answers:
            if role:
                print(f"{role}:")
            if args.json:
                print(json.dumps(body, indent=2))
            else:
                print(status_text(body))
                print(f"answered by {answered_by(body)}")
    return 2 if silent else 0


def _any_json(payload: bytes) -> dict | None:
    try:
        return json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "reset", help="ask the monitor to release a latched STOP; waits for its answer",
        description="Sends a reset request signed with the operator's key and prints the "
        "monitor's answer. Exit 0 accepted, 1 refused (reason printed), 2 no answer.")
    add_zenoh_args(p, default_connect=True)
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
    p.add_argument("--monitor-key", action="append", default=[], metavar="FILE",
                   help="the monitor's public key (as for watch; repeat for several): only an "
                   "answer it signed is believed (default none: the answer is shown as NOT "
                   "authenticated)")
    add_role_arg(p, many=True, what="name every monitor of the cell: each latched one gets "
                 "its own signed request and answers; exit 0 only when all accepted")
    p.set_defaults(func=cmd_reset)

    p = subparsers.add_parser(
        "status", help="query the monitor's status",
        description="Prints the status of the cell's monitor as a summary for an operator "
        "(command and reasons, latch and reset, cameras, faults, muted zones, zone sets, "
        "commissioning, uptime), or with --json the whole answer as JSON; every monitor that "
        "answers, as a second one on the cell is a fault to see. With --role: each named "
        "monitor's status under a line with its role; exit 2 when any did not answer.")
    add_zenoh_args(p, default_connect=True)
    add_role_arg(p, many=True, what="each one's status is printed under its role's name")
    p.add_argument("--timeout", type=float, default=3.0,
                   help="s to wait for an answer (default 3)")
    p.add_argument("--json", action="store_true",
                   help="print the monitor's answer as JSON, every field (for scripts and "
                   "`monitor commission report --status`; default: a text summary)")
    add_monitor_key_arg(p)
    p.set_defaults(func=cmd_status)
