"""``monitor objects accept --camera C --zone Z``: an operator who has looked at an object put
into a zone since commissioning accepts it, signed with their key (docs/occlusion.md, "What
changed since commissioning"); ``monitor objects list`` shows the objects standing. Until
then the object holds the cell in STOP and every reset is refused; accepted, it is an
occluder declared at run time (the floor behind it stays unseen) and the commissioned status
says the cell has changed.

Exit 0 accepted, 1 refused (the reason printed), 2 no answer (or bad input)."""

from __future__ import annotations

import argparse
import contextlib
import sys
import time

from monitor.bus.session import default_instance, open_session
from monitor.cli.keys import KEY_DIR
from monitor.cli.operator import first_status, operator_key_path
from monitor.cli.role_arg import add_role_arg
from monitor.cli.roles import no_answer, role_keys
from monitor.cli.status_text import changed_lines
from monitor.cli.zenoh_args import add_zenoh_args, bounded, bus_config, nothing_found_hint
from monitor.errors import ConfigError
from monitor.signals import Interrupted, StopSignals, call_interruptible
from monitor.wire.answers import request_answer
from monitor.wire.object_accepts import accept_payload
from monitor.wire.signing import load_private_key, load_public_key


def cmd_accept(args: argparse.Namespace) -> int:
    key_path = operator_key_path(args)
    if key_path is None:  # acceptances are never unsigned
        raise ConfigError(f"monitor objects accept: no key for {args.operator} (--key, or "
                          f"{KEY_DIR}/{args.operator}.key); an acceptance must be signed")
    signer = load_private_key(key_path)
    monitor_keys = (tuple(load_public_key(k) for k in args.monitor_key)
                    if args.monitor_key else None)
    if monitor_keys is None:
        print("monitor objects accept: no --monitor-key: the answer is NOT authenticated",
              file=sys.stderr, flush=True)
    with StopSignals(name="monitor objects accept") as stop:
        bus = bus_config(args, instance=args.instance or default_instance("accept"))
        keys = role_keys(bus, args.role)
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 130
        answer = None
        with bounded(session, "monitor objects accept") as session:
            started = time.monotonic()
            status = first_status(session, keys, args.timeout, stop)  # the monitor's boot
            if status is None:
                if stop.is_set():
                    return 130
                raise no_answer("monitor objects accept", keys.status, args.timeout, bus,
                                session, stop, args.role)
            boot = status.get("boot") if isinstance(status.get("boot"), str) else ""
            payload = accept_payload(args.operator, args.camera, args.zone,
                                     cell=status.get("cell") or bus.cell, boot=boot,
                                     note=args.note, request_id=args.request_id)
            signature = signer.sign(keys.objects_accept, payload)
            left = args.timeout - (time.monotonic() - started)
            if left > 0:
                with contextlib.suppress(Interrupted):
                    answer = call_interruptible(lambda: request_answer(
                        session, keys.objects_accept, payload, signature, left,
                        monitor_keys), stop)
        if stop.is_set():
            return 130
    if answer is None:
        raise ConfigError(f"monitor objects accept: no monitor answered on "
                          f"{keys.objects_accept} within {args.timeout:g} s"
                          + (" (with an answer signed by --monitor-key)" if monitor_keys
                             else "") + f"; {nothing_found_hint(bus)}")
    verdict = "accepted" if answer["accepted"] else "REFUSED"
    by = f"{args.role}: " if args.role else ""
    print(f"{by}object in zone {args.zone} on {args.camera} by {args.operator} {verdict}: "
          f"{answer.get('reason', '')}")
    if not answer["accepted"]:
        print(f"monitor objects accept: refused by the {answer.get('stage', 'monitor')}",
              file=sys.stderr)
    return 0 if answer["accepted"] else 1


def cmd_list(args: argparse.Namespace) -> int:
    """The objects standing since commissioning, as the monitor's status says (exit 0; 2 when
    nothing answered)."""
    with StopSignals(name="monitor objects list") as stop:
        bus = bus_config(args, instance=args.instance or default_instance("objects"))
        keys = role_keys(bus, args.role)
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 130
        with bounded(session, "monitor objects list") as session:
            status = first_status(session, keys, args.timeout, stop)
            if status is None:
                if stop.is_set():
                    return 130
                raise no_answer("monitor objects list", keys.status, args.timeout, bus,
                                session, stop, args.role)
    lines = changed_lines(status.get("changed_since_commissioning"))
    if status.get("changes_unwatched"):
        lines.append(str(status["changes_unwatched"]))
    print("\n".join(lines) if lines else "no object put into the zones since commissioning "
          "stands (cameras watched: " + (", ".join(map(str, status.get("changes_watched")
                                                        or [])) or "none") + ")")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "objects", help="objects put into the zones since commissioning: accept one (signed)",
        description="Objects that stand in the protective and warning zones and are not in "
        "the commissioning reference (docs/occlusion.md).")
    sub = p.add_subparsers(dest="objects_command", required=True, metavar="COMMAND")
    a = sub.add_parser(
        "accept", help="accept the object standing in a zone (looked at; signed, audited)",
        description="Sends an acceptance signed with the operator's key and prints the "
        "monitor's answer. Every object the camera sees standing in the zone and nobody "
        "accepted yet is accepted: it stops holding the cell by itself, the floor behind it "
        "stays unseen (a person lost there is held until seen free), and the status says the "
        "cell has changed since commissioning. Exit 0 accepted, 1 refused (reason printed), "
        "2 no answer.")
    a.add_argument("--camera", required=True, help="the camera id that sees the object, as "
                   "the alert names it (required)")
    a.add_argument("--zone", required=True, help="the zone it stands in, as the alert names "
                   "it (required)")
    a.add_argument("--operator", required=True,
                   help="operator id, as in the monitor's operators file (required)")
    a.add_argument("--key", metavar="FILE", help="the operator's private key (default "
                   f"{KEY_DIR}/<operator>.key when it exists)")
    a.add_argument("--note", default="", help="what it is, for the audit (default empty)")
    add_zenoh_args(a, default_connect=True)
    add_role_arg(a, many=False, what="the object is accepted by that monitor (each monitor of "
                 "a cell has its own cameras)")
    a.add_argument("--request-id", default="",
                   help="unique id of this request (default <operator>-<time>-<random>)")
    a.add_argument("--timeout", type=float, default=3.0,
                   help="s to wait for the monitor's answer (default 3)")
    a.add_argument("--monitor-key", action="append", default=[], metavar="FILE",
                   help="the monitor's public key (repeat for several): only an answer it "
                   "signed is believed (default none: the answer is NOT authenticated)")
    a.set_defaults(func=cmd_accept)

    li = sub.add_parser(
        "list", help="the objects standing since commissioning, accepted or not",
        description="Prints each object the monitor sees standing in its zones since "
        "commissioning (camera, place, zones, accepted by whom and when, or the command that "
        "accepts it), from the monitor's status. Exit 0; 2 when nothing answered.")
    add_zenoh_args(li, default_connect=True)
    add_role_arg(li, many=False, what="that monitor's objects")
    li.add_argument("--timeout", type=float, default=3.0,
                    help="s to wait for the monitor's status (default 3)")
    li.set_defaults(func=cmd_list)
