"""``--monitor-key FILE`` on the commands that send the monitor a signed request (mute, objects
accept, zones apply, case select): the option and the keys it names, without the bus, so that
registering ``zones apply`` or ``case select`` does not load Zenoh for every ``monitor zones``
command. The monitor signs its answers and names the request (``monitor.wire.answers``): only
such an answer is believed with the option."""

from __future__ import annotations

import argparse
import sys

from monitor.wire.signing import load_public_key


def add_monitor_key_arg(p: argparse.ArgumentParser) -> None:
    """``--monitor-key FILE``: the monitor's public key its answers are believed by."""
    p.add_argument("--monitor-key", action="append", default=[], metavar="FILE",
                   help="the monitor's public key (repeat for several): only an answer it "
                   "signed is believed (default none: the answer is NOT authenticated)")


def monitor_keys_of(args: argparse.Namespace, command: str) -> tuple | None:
    """The ``--monitor-key`` keys (None, said on stderr, when none is given: then any answer
    is taken for the monitor's)."""
    if not args.monitor_key:
        print(f"{command}: no --monitor-key: the answer is NOT authenticated",
              file=sys.stderr, flush=True)
        return None
    return tuple(load_public_key(k) for k in args.monitor_key)
