"""One operator's signed request to the running monitor and its answer, as ``monitor mute``
and ``monitor objects accept`` send it: read the monitor's status (its cell and boot, which
the request names), sign the request with the operator's key, wait for the answer
(``monitor.wire.answers.request_answer``) and print one line. With ``--monitor-key`` only the
monitor's signed answer to this very request is believed: any other (unsigned, signed by
another key, a replayed answer to another request) is ignored, the wait goes on, and what was
ignored is said on stderr (with the no-answer error when nothing else came); without it the
answer is NOT authenticated (said on stderr).

Exit 0 accepted, 1 refused (the reason printed; the stage that refused it on stderr), 2 no
answer or bad input (a ``ConfigError``, one line), 130 interrupted. Never unsigned: without
the operator's key nothing is sent.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

from monitor.bus.session import BusKeys, default_instance, open_session
from monitor.cli.keys import KEY_DIR
from monitor.cli.operator import first_status, operator_key_path, status_ignored_line
from monitor.cli.role_arg import add_role_arg
from monitor.cli.roles import no_answer, role_keys
from monitor.cli.zenoh_args import add_zenoh_args, bounded, bus_config, nothing_found_hint
from monitor.errors import ConfigError
from monitor.signals import Interrupted, StopSignals, call_interruptible
from monitor.wire.answers import ignored_text, request_answer
from monitor.wire.signing import Signer, load_private_key


@dataclass(frozen=True)
class SignedAsk:
    """One kind of request as its command sends it."""

    command: str  # "monitor mute": how its lines and errors begin
    instance: str  # the Zenoh instance name's stem ("mute" -> mute-<host>-<pid>-...)
    key: Callable[[BusKeys], str]  # the request's key of that monitor (role)
    payload: Callable[[str, str], bytes]  # (cell, boot) from the status -> the request body
    subject: str  # what the answer line says was asked: "mute of zone z1"


def add_signed_args(p: argparse.ArgumentParser, role_what: str,
                    note_help: str | None = None) -> None:
    """The options every such command has, in the order its help lists them: the operator and
    their key, a ``--note`` when ``note_help`` says what it is for, the Zenoh options, the
    monitor's ``--role`` (``role_what``: what naming it means), the request id, the
    timeout."""
    p.add_argument("--operator", required=True,
                   help="operator id, as in the monitor's operators file (required)")
    p.add_argument("--key", metavar="FILE", help="the operator's private key (default "
                   f"{KEY_DIR}/<operator>.key when it exists)")
    if note_help is not None:
        p.add_argument("--note", default="", help=note_help)
    add_zenoh_args(p, default_connect=True)
    add_role_arg(p, many=False, what=role_what)
    p.add_argument("--request-id", default="",
                   help="unique id of this request (default <operator>-<time>-<random>)")
    p.add_argument("--timeout", type=float, default=3.0,
                   help="s to wait for the monitor's answer (default 3)")


def operator_signer(args: argparse.Namespace, command: str, why: str) -> Signer:
    """The operator's key (``--key`` or the default file); a ConfigError ending in ``why``
    when there is none: these requests are never unsigned."""
    key_path = operator_key_path(args)
    if key_path is None:
        raise ConfigError(f"{command}: no key for {args.operator} (--key, or "
                          f"{KEY_DIR}/{args.operator}.key); {why}")
    return load_private_key(key_path)


def ask_signed(args: argparse.Namespace, ask: SignedAsk, signer: Signer,
               monitor_keys: tuple | None = None) -> int:
    """Send the request, print the answer line; the exit code. ``monitor_keys``: only an
    answer signed by one of them is believed (None: the first well-formed one)."""
    with StopSignals(name=ask.command) as stop:
        bus = bus_config(args, instance=args.instance or default_instance(ask.instance))
        keys = role_keys(bus, args.role)
        key = ask.key(keys)
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 130
        answer = None
        ignored: list[str] = []  # answers not believed (``monitor_keys``): someone else's
        with bounded(session, ask.command) as session:
            started = time.monotonic()
            # the monitor's boot (with ``monitor_keys``: from its signed answer only)
            skipped: list[str] = []
            status = first_status(session, keys, args.timeout, stop, monitor_keys, skipped)
            if (line := status_ignored_line(ask.command, keys.status, skipped)):
                print(line, file=sys.stderr, flush=True)
            if status is None:
                if stop.is_set():
                    return 130
                raise no_answer(ask.command, keys.status, args.timeout, bus, session, stop,
                                args.role)
            boot = status.get("boot") if isinstance(status.get("boot"), str) else ""
            payload = ask.payload(status.get("cell") or bus.cell, boot)
            signature = signer.sign(key, payload)
            left = args.timeout - (time.monotonic() - started)
            if left > 0:
                with contextlib.suppress(Interrupted):
                    answer = call_interruptible(lambda: request_answer(
                        session, key, payload, signature, left, monitor_keys, ignored),
                        stop)
        if stop.is_set():
            return 130
    if answer is None:
        raise ConfigError(f"{ask.command}: no monitor answered on {key} within "
                          f"{args.timeout:g} s"
                          + (" (with an answer signed by --monitor-key)" if monitor_keys
                             else "")
                          + (f"; {ignored_text(ignored)}: someone else answers there"
                             if ignored else "") + f"; {nothing_found_hint(bus)}")
    if ignored:
        print(f"{ask.command}: {ignored_text(ignored)}: someone else answers on {key}",
              file=sys.stderr, flush=True)
    verdict = "accepted" if answer["accepted"] else "REFUSED"
    by = f"{args.role}: " if args.role else ""
    print(f"{by}{ask.subject} by {args.operator} {verdict}: {answer.get('reason', '')}")
    if not answer["accepted"]:
        print(f"{ask.command}: refused by the {answer.get('stage', 'monitor')}",
              file=sys.stderr)
    return 0 if answer["accepted"] else 1
