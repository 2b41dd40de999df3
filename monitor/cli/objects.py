"""``monitor objects accept --camera C --zone Z``: an operator who has looked at an object put
into a zone since commissioning accepts it, signed with their key (docs/occlusion.md, "What
changed since commissioning"); ``monitor objects list`` shows the objects standing. Until
then the object holds the cell in STOP and every reset is refused; accepted, it is an
occluder declared at run time (the floor behind it stays unseen) and the commissioned status
says the cell has changed.

Exit 0 accepted, 1 refused (the reason printed), 2 no answer (or bad input)."""

from __future__ import annotations

import argparse

from monitor.bus.session import default_instance, open_session
from monitor.cli.monitor_key_arg import add_monitor_key_arg, monitor_keys_of
from monitor.cli.operator import first_status
from monitor.cli.role_arg import add_role_arg
from monitor.cli.roles import no_answer, role_keys
from monitor.cli.signed_ask import SignedAsk, add_signed_args, ask_signed, operator_signer
from monitor.cli.status_text import changed_lines
from monitor.cli.zenoh_args import add_zenoh_args, bounded, bus_config
from monitor.signals import Interrupted, StopSignals, call_interruptible
from monitor.wire.object_accepts import accept_payload


def cmd_accept(args: argparse.Namespace) -> int:
    signer = operator_signer(args, "monitor objects accept", "an acceptance must be signed")
    monitor_keys = monitor_keys_of(args, "monitor objects accept")
    return ask_signed(args, SignedAsk(
        "monitor objects accept", "accept", lambda keys: keys.objects_accept,
        lambda cell, boot: accept_payload(args.operator, args.camera, args.zone, cell=cell,
                                          boot=boot, note=args.note,
                                          request_id=args.request_id),
        f"object in zone {args.zone} on {args.camera}"), signer, monitor_keys)


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
    add_signed_args(a, "the object is accepted by that monitor (each monitor of a cell has "
                    "its own cameras)", note_help="what it is, for the audit (default empty)")
    add_monitor_key_arg(a)
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
