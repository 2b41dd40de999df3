"""Operator commands: ``monitor reset`` (release a latched STOP) and ``monitor status``."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from monitor.bus import BusKeys, default_instance, open_session
from monitor.cli.keys import KEY_DIR
from monitor.cli.zenoh_args import (
    add_zenoh_args,
    bounded,
    bus_config,
    nothing_found_hint,
    safe_json,
)
from monitor.errors import ConfigError
from monitor.resets import latch_of_status, request_reset, reset_payload
from monitor.signals import Interrupted, StopSignals, call_interruptible
from monitor.signing import load_private_key


def _operator_key_path(args: argparse.Namespace) -> Path | None:
    if args.key:
        return Path(args.key)
    default = (KEY_DIR / f"{args.operator}.key").expanduser()
    return default if default.exists() else None


def cmd_reset(args: argparse.Namespace) -> int:
    """Exit 0 when the monitor accepted the reset, 1 when it refused (reason printed), 2 when
    nothing answered."""
    with StopSignals(name="monitor reset") as stop:
        bus = bus_config(args, instance=args.instance or default_instance("reset"))
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
        with bounded(session, "monitor reset") as session:
            started = time.monotonic()
            answer = None
            # the reset names the monitor's boot and the latch it releases (signed into it)
            status = _first_status(session, keys, args.timeout, stop)
            if status is None:
                if stop.is_set():
                    return 130
                raise ConfigError(f"monitor reset: no monitor answered on {keys.status} within "
                                  f"{args.timeout:g} s; {nothing_found_hint(bus)}")
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
                          f"{args.timeout:g} s; {nothing_found_hint(bus)}")
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
            body = safe_json(payload)
            if isinstance(body.get("boot"), str):
                return body
        stop.wait(min(0.2, max(0.0, left)))  # nothing routed yet: ask again
    return None


def cmd_status(args: argparse.Namespace) -> int:
    with StopSignals(name="monitor status") as stop:
        bus = bus_config(args, instance=args.instance or default_instance("status"))
        keys = BusKeys.of(bus.key_prefix)
        answers = 0
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 130
        started = time.monotonic()
        with bounded(session, "monitor status") as session:
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
                          f"{nothing_found_hint(bus)}")
    return 0

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
    p.set_defaults(func=cmd_reset)

    p = subparsers.add_parser("status", help="query the monitor's status")
    add_zenoh_args(p, default_connect=True)
    p.add_argument("--timeout", type=float, default=3.0,
                   help="s to wait for an answer (default 3)")
    p.set_defaults(func=cmd_status)
