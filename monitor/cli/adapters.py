"""`monitor bridge plc|opcua|ros2`: an adapter process for the robot side (docs/adapters.md).

Each kind is a module of ``monitor.adapters`` with two functions:

- ``add_arguments(parser)``: its own options (address, port, register map, security ...);
- optionally ``check_arguments(args)``: raise a ConfigError for bad options before Zenoh opens;
- ``make_outputs(args, session, keys) -> list[Output]``: its outputs, started (a server on its
  own thread, a Zenoh publisher); they are closed in reverse order when the adapter stops.

The rest is shared here: the Zenoh options, the consumer rule's options (the same as `monitor
watch`: pinned monitor keys, ttl cap, clock sync, liveliness), the signals, and the follower's
loop (``monitor.adapters.follower``).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import threading

from monitor.adapters.follower import DEFAULT_TICK_S, Follower, subscribe
from monitor.errors import ConfigError
from monitor.signals import (
    Interrupted,
    StopSignals,
    call_interruptible,
    close_bounded,
    exit_if_stopped,
)
from monitor.wire.cell_consumer import subscribe_cell
from monitor.wire.consumer import DEFAULT_CLOCK_SYNC_MS
from monitor.wire.inbox import DEFAULT_BOUND, Inbox

# kind -> (module of monitor.adapters, help)
KINDS: dict[str, tuple[str, str]] = {}
KINDS["plc"] = ("modbus", "Modbus TCP server: the verdict in a documented register map for a "
                 "PLC (docs/plc.md)")
KINDS["ros2"] = ("ros2", "ROS 2 topics over Zenoh in rmw_zenoh's format: speed override, "
                  "diagnostics, command JSON (no ROS installation needed; docs/ros2.md)")
KINDS["opcua"] = ("opcua", "OPC UA server: the safety state as read-only variables "
                  "(docs/opcua.md)")


def add_consumer_args(p: argparse.ArgumentParser) -> None:
    """The consumer rule's options, as `monitor watch` has them."""
    p.add_argument("--monitor-key", action="append", default=[], metavar="FILE",
                   help="the monitor's public key file (ed25519:...); only commands signed by "
                   "it count (repeatable; required unless --unauthenticated)")
    p.add_argument("--unauthenticated", action="store_true",
                   help="follow unsigned commands (a bench only: anyone on the bus can forge "
                   "RUN; default off)")
    p.add_argument("--ttl-ms", type=float, default=1000.0,
                   help="cap on every command's ttl_ms (default 1000)")
    p.add_argument("--clock-sync-ms", type=float, default=DEFAULT_CLOCK_SYNC_MS,
                   help="how closely this host's clock agrees with the monitor's (default "
                   f"{DEFAULT_CLOCK_SYNC_MS:g})")
    p.add_argument("--follow", metavar="INSTANCE",
                   help="only accept this monitor instance (default: any, one at a time)")
    p.add_argument("--no-liveliness", action="store_true",
                   help="do not require the liveliness token (not recommended; default off)")
    from monitor.cli.watch import add_expect_arg

    add_expect_arg(p)
    p.add_argument("--camera", action="append", default=[], dest="cameras", metavar="ID",
                   help="camera ids to report ok bits for (repeatable; default none)")
    p.add_argument("--tick", type=float, default=DEFAULT_TICK_S,
                   help=f"s between two updates of the outputs (default {DEFAULT_TICK_S:g})")
    p.add_argument("--duration", type=float, default=None,
                   help="exit after this many seconds (default: run until SIGINT/SIGTERM)")
    p.add_argument("--inbox", type=int, default=DEFAULT_BOUND, metavar="N",
                   help=f"messages of each kind held while busy (default {DEFAULT_BOUND})")


def register_bridges(bsub, add_zenoh_args) -> None:
    """Add one `monitor bridge KIND` per entry of ``KINDS``."""
    for kind, (module, text) in KINDS.items():
        p = bsub.add_parser(kind, help=text)
        add_zenoh_args(p, default_connect=True)
        add_consumer_args(p)
        importlib.import_module(f"monitor.adapters.{module}").add_arguments(p)
        p.set_defaults(func=cmd_bridge, adapter_module=module)


def cmd_bridge(args: argparse.Namespace) -> int:
    from monitor.bus.session import BusKeys, default_instance, open_session
    from monitor.cli.watch import make_watchdog
    from monitor.cli.zenoh_args import bus_config

    name = f"monitor bridge {args.bridge_kind}"
    if not args.monitor_key and not args.expect and not args.unauthenticated:
        raise ConfigError(f"{name}: give --monitor-key FILE (the monitor's public key), or "
                          "--unauthenticated for a bench")
    if args.tick <= 0 or args.inbox < 1:
        raise ConfigError(f"{name}: --tick must be > 0 and --inbox at least 1")
    module = importlib.import_module(f"monitor.adapters.{args.adapter_module}")
    if hasattr(module, "check_arguments"):  # bad options fail before Zenoh opens
        module.check_arguments(args)
    with StopSignals(name=name) as stop:
        bus = bus_config(args, instance=args.instance or default_instance(args.bridge_kind))
        keys = BusKeys.of(bus.key_prefix)
        dog = make_watchdog(args, bus, keys)
        inbox = Inbox(args.inbox)
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 0
        entities, outputs = [], []
        try:
            entities = (subscribe_cell(session, bus.key_prefix, inbox) if args.expect
                        else subscribe(session, keys, inbox))
            outputs = module.make_outputs(args, session, keys)
            print(f"{name}: following "
                  f"{'the expected monitors' if args.expect else keys.command} -> "
                  f"{', '.join(o.name for o in outputs)}", file=sys.stderr, flush=True)
            follower = Follower(dog, inbox, cameras=tuple(args.cameras))
            follower.run(outputs, stop, args.tick, args.duration)
        finally:
            _close_outputs(outputs, name)
            if not close_bounded(session, 1.0, entities):
                print(f"{name}: Zenoh did not close within 1 s; exiting anyway",
                      file=sys.stderr, flush=True)
        return exit_if_stopped(stop)


def _close_outputs(outputs: list, name: str) -> None:
    """Close in reverse order, each bounded by its own thread (a hung server never keeps
    the process)."""
    for out in reversed(outputs):
        t = threading.Thread(target=out.close, daemon=True)
        t.start()
        t.join(timeout=1.0)
        if t.is_alive():
            print(f"{name}: output {out.name} did not close within 1 s", file=sys.stderr,
                  flush=True)
