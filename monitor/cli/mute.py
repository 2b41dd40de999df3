"""``monitor mute ZONE --for 60s``: ask the monitor to mute a zone for a bounded time, signed
with the operator's key; ``--end`` ends the zone's mute early (docs/muting.md).

Exit 0 accepted, 1 refused (the reason printed), 2 no answer (or bad input)."""

from __future__ import annotations

import argparse
import contextlib
import re
import sys
import time

from monitor.bus.session import default_instance, open_session
from monitor.cases.mute_requests import mute_payload, request_mute
from monitor.cli.keys import KEY_DIR
from monitor.cli.operator import first_status, operator_key_path
from monitor.cli.role_arg import add_role_arg
from monitor.cli.roles import no_answer, role_keys
from monitor.cli.zenoh_args import add_zenoh_args as _add_zenoh_args
from monitor.cli.zenoh_args import bounded as _bounded
from monitor.cli.zenoh_args import bus_config as _bus_config
from monitor.cli.zenoh_args import nothing_found_hint as _nothing_found_hint
from monitor.errors import ConfigError
from monitor.signals import Interrupted, StopSignals, call_interruptible
from monitor.wire.signing import load_private_key

_UNITS = {"": 1.0, "s": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0}


def parse_duration(text: str) -> float:
    """``60s``, ``2m``, ``1.5h``, ``90`` (seconds) as seconds; ConfigError otherwise."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*(s|m|min|h|)\s*", text)
    if m is None or float(m.group(1)) <= 0:
        raise ConfigError(f"monitor mute: --for {text!r}: give a positive duration such as "
                          "60s, 2m or 90")
    return float(m.group(1)) * _UNITS[m.group(2)]


def cmd_mute(args: argparse.Namespace) -> int:
    if args.end == (args.duration is not None):
        raise ConfigError("monitor mute: give either --for DURATION (mute) or --end "
                          "(end the zone's mute now)")
    duration = 0.0 if args.end else parse_duration(args.duration)
    key_path = operator_key_path(args)
    if key_path is None:  # muting is never unsigned
        raise ConfigError(f"monitor mute: no key for {args.operator} (--key, or "
                          f"{KEY_DIR}/{args.operator}.key); mutes must be signed")
    signer = load_private_key(key_path)
    with StopSignals(name="monitor mute") as stop:
        bus = _bus_config(args, instance=args.instance or default_instance("mute"))
        keys = role_keys(bus, args.role)
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 130
        answer = None
        with _bounded(session, "monitor mute") as session:
            started = time.monotonic()
            status = first_status(session, keys, args.timeout, stop)  # the monitor's boot
            if status is None:
                if stop.is_set():
                    return 130
                raise no_answer("monitor mute", keys.status, args.timeout, bus, session, stop,
                                args.role)
            boot = status.get("boot") if isinstance(status.get("boot"), str) else ""
            payload = mute_payload(args.operator, args.zone, duration, end=args.end,
                                   cell=status.get("cell") or bus.cell, boot=boot,
                                   request_id=args.request_id)
            signature = signer.sign(keys.mute, payload)
            left = args.timeout - (time.monotonic() - started)
            if left > 0:
                with contextlib.suppress(Interrupted):
                    answer = call_interruptible(lambda: request_mute(
                        session, keys.mute, payload, signature, left), stop)
        if stop.is_set():
            return 130
    if answer is None:
        raise ConfigError(f"monitor mute: no monitor answered on {keys.mute} within "
                          f"{args.timeout:g} s; {_nothing_found_hint(bus)}")
    verdict = "accepted" if answer["accepted"] else "REFUSED"
    what = "end of the mute of" if args.end else "mute of"
    by = f"{args.role}: " if args.role else ""
    print(f"{by}{what} zone {args.zone} by {args.operator} {verdict}: "
          f"{answer.get('reason', '')}")
    if not answer["accepted"]:
        print(f"monitor mute: refused by the {answer.get('stage', 'monitor')}", file=sys.stderr)
    return 0 if answer["accepted"] else 1


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "mute", help="mute a zone for a bounded time (signed); --end ends it early",
        description="Sends a mute request signed with the operator's key and prints the "
        "monitor's answer. The zone file says who may mute which zone, for how long and what "
        "a muted zone is checked as (docs/muting.md). Exit 0 accepted, 1 refused (reason "
        "printed), 2 no answer.")
    p.add_argument("zone", help="the zone id, as in the zone file")
    p.add_argument("--for", dest="duration", metavar="DURATION",
                   help="how long: 60s, 2m, 90 (seconds); at most the zone's mute max_s")
    p.add_argument("--end", action="store_true",
                   help="end the zone's mute now instead (default off)")
    p.add_argument("--operator", required=True,
                   help="operator id, as in the monitor's operators file (required)")
    p.add_argument("--key", metavar="FILE", help="the operator's private key (default "
                   f"{KEY_DIR}/<operator>.key when it exists)")
    _add_zenoh_args(p, default_connect=True)
    add_role_arg(p, many=False, what="the zone is muted in that monitor's zones only (each "
                 "monitor of a cell has its own zone file and mutes)")
    p.add_argument("--request-id", default="",
                   help="unique id of this request (default <operator>-<time>-<random>)")
    p.add_argument("--timeout", type=float, default=3.0,
                   help="s to wait for the monitor's answer (default 3)")
    p.set_defaults(func=cmd_mute)
