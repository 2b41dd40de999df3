"""``--role ROLE`` on the operator commands (status, reset, mute, zones apply): the option
alone, without the bus (``monitor.cli.roles`` turns a role into keys and asks who answers), so
that registering ``zones apply`` does not load Zenoh for every ``monitor zones`` command."""

from __future__ import annotations

import argparse

from monitor.wire.busconfig import checked_role


def parse_role(text: str) -> str:
    """A role as the monitor's ``[bus] role`` allows it; argparse's error otherwise."""
    try:
        return checked_role(text) if text else ""
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_role_arg(p: argparse.ArgumentParser, *, many: bool, what: str) -> None:
    """``--role ROLE`` (repeatable when ``many``) on a command; ``what`` says what it does."""
    if many:
        p.add_argument("--role", action="append", default=[], metavar="ROLE", type=parse_role,
                       help=f"a monitor of the cell by its [bus] role (repeatable); {what} "
                       "(default: the cell's only monitor)")
    else:
        p.add_argument("--role", default="", metavar="ROLE", type=parse_role,
                       help=f"the monitor of the cell with this [bus] role; {what} "
                       "(default: the cell's only monitor)")
