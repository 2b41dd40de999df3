"""Zenoh options and helpers shared by the bus commands (watch, bridge, router, reset, status).

``add_zenoh_args`` gives a parser the Zenoh option group; ``bus_config`` turns those options
into a :class:`~monitor.bus.session.BusConfig`; ``nothing_found_hint`` says where a command looked
when nothing answered; ``bounded`` closes a session with a deadline.
"""

from __future__ import annotations

import argparse
import json
import sys

from monitor.errors import ConfigError
from monitor.signals import close_bounded
from monitor.wire.busconfig import MODES, BusConfig

# `monitor run` without a config listens here (monitor.config.DEMO_LISTEN); the operator
# commands connect here when no endpoint is given, so they find a default service on this host.
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"

def add_zenoh_args(p: argparse.ArgumentParser, default_mode: str = "peer",
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


def bus_config(args: argparse.Namespace, **over) -> BusConfig:
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


def where(bus: BusConfig) -> str:
    """Where a command looked, for 'found nothing' messages."""
    ends = [*bus.connect, *(f"listen {e}" for e in bus.listen)] or [
        f"the --zenoh-config file {bus.zenoh_config_file}"]
    return ", ".join(ends)


def nothing_found_hint(bus: BusConfig) -> str:
    return (f"looked via {where(bus)} on cell {bus.cell!r}; is `monitor run` up? try "
            f"--connect tcp/<monitor host>:7447 and --cell <name> (see `monitor status --help`)")



class bounded:
    """``with bounded(session):`` closes the session with a deadline (``close_bounded``)."""

    def __init__(self, session, name: str, undeclare: list | None = None) -> None:
        self.session, self.name = session, name
        self.undeclare = undeclare if undeclare is not None else []

    def __enter__(self):
        return self.session

    def __exit__(self, *exc) -> None:
        if not close_bounded(self.session, 1.0, self.undeclare):
            print(f"{self.name}: Zenoh did not close within 1 s; exiting anyway",
                  file=sys.stderr, flush=True)



def safe_json(payload: bytes) -> dict:
    try:
        body = json.loads(payload)
        return body if isinstance(body, dict) else {"value": body}
    except (ValueError, UnicodeDecodeError, RecursionError):
        return {"invalid": payload[:200].hex()}
