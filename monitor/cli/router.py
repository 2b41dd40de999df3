"""``monitor router``: a Zenoh router until SIGINT/SIGTERM."""

from __future__ import annotations

import argparse
import sys

from monitor.bus.session import default_instance, open_session
from monitor.cli.zenoh_args import add_zenoh_args, bounded, bus_config
from monitor.errors import ConfigError
from monitor.signals import (
    Interrupted,
    StopSignals,
    call_interruptible,
    exit_if_stopped,
    wait_for_stop,
)


def cmd_router(args: argparse.Namespace) -> int:
    with StopSignals(name="monitor router") as stop:
        bus = bus_config(args, instance=args.instance or default_instance("router"))
        if not bus.listen and not args.zenoh_config:
            raise ConfigError("monitor router: give --listen ENDPOINT (e.g. tcp/127.0.0.1:7447;"
                              " tcp/0.0.0.0:7447 opens it to the network) or --zenoh-config")
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 0
        with bounded(session, "monitor router") as session:
            print(f"monitor router: zid {session.zid()} listening on {list(bus.listen)}",
                  file=sys.stderr, flush=True)
            wait_for_stop(stop)
        return exit_if_stopped(stop)

def register(subparsers) -> None:
    p = subparsers.add_parser("router", help="run a Zenoh router until SIGINT/SIGTERM")
    add_zenoh_args(p, default_mode="router")
    p.set_defaults(func=cmd_router)
