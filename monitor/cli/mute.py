"""``monitor mute ZONE --for 60s``: ask the monitor to mute a zone for a bounded time, signed
with the operator's key; ``--end`` ends the zone's mute early (docs/muting.md).

The monitor signs its answers and names the request they answer: with ``--monitor-key`` no
other responder on the mute key is believed (``monitor.cli.signed_ask``).

Exit 0 accepted, 1 refused (the reason printed), 2 no answer (or bad input)."""

from __future__ import annotations

import argparse
import re

from monitor.cases.mute_requests import mute_payload
from monitor.cli.monitor_key_arg import add_monitor_key_arg, monitor_keys_of
from monitor.cli.signed_ask import SignedAsk, add_signed_args, ask_signed, operator_signer
from monitor.errors import ConfigError

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
    signer = operator_signer(args, "monitor mute", "mutes must be signed")
    monitor_keys = monitor_keys_of(args, "monitor mute")
    what = "end of the mute of" if args.end else "mute of"
    return ask_signed(args, SignedAsk(
        "monitor mute", "mute", lambda keys: keys.mute,
        lambda cell, boot: mute_payload(args.operator, args.zone, duration, end=args.end,
                                        cell=cell, boot=boot, request_id=args.request_id),
        f"{what} zone {args.zone}"), signer, monitor_keys)


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
    add_signed_args(p, "the zone is muted in that monitor's zones only (each monitor of a "
                    "cell has its own zone file and mutes)")
    add_monitor_key_arg(p)
    p.set_defaults(func=cmd_mute)
