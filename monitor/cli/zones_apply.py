"""``monitor zones apply``: ask the running monitor to decide with a changed zone file.

Reads the zone file, validates it (the one-line error of ``monitor zones validate``), computes
its hash (``monitor zones hash``), signs a request naming that hash with the operator's key
(``monitor.cases.zone_apply``) and prints the monitor's answer. The monitor re-reads the file from
its own configured path and applies it only when that file has the signed hash. The monitor
signs its answer and names the request it answers: with ``--monitor-key`` no other responder
on the key is believed (``monitor.cli.signed_ask``).
Exit 0 applied, 1 refused (reason printed), 2 bad input or no monitor answered.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from monitor.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    from monitor.cli.keys import KEY_DIR
    from monitor.cli.monitor_key_arg import add_monitor_key_arg
    from monitor.cli.role_arg import add_role_arg
    from monitor.cli.zenoh_args import add_zenoh_args as _add_zenoh_args

    p = sub.add_parser(
        "apply", help="apply a changed zone file to the running monitor (signed by an operator)",
        description="Validates the zone file, signs its zone-set hash with the operator's key "
        "and asks the running monitor to apply it. The monitor re-reads the file from its own "
        "[zones] file path, refuses unless that file has the signed hash, validates it, and "
        "then decides with it (STOP until every camera is checked on the new zones, then "
        "clear_time). Exit 0 applied, 1 refused, 2 no answer or bad input.")
    _add_zenoh_args(p, default_connect=True)
    add_role_arg(p, many=False, what="its zone file is read, signed and applied (each monitor of "
                 "a cell has its own zone file)")
    p.add_argument("--operator", required=True, help="operator id, as in the monitor's "
                   "operators file (required)")
    p.add_argument("--key", metavar="FILE", help="the operator's private key (default "
                   f"{KEY_DIR}/<operator>.key when it exists)")
    p.add_argument("--zones", type=Path, metavar="FILE",
                   help="the zone file to validate and sign (default: the file the monitor "
                   "runs with, from its status; on the monitor's host), or the draft beside it "
                   "(cell.draft.yaml: a console edit that weakens protection; the monitor then "
                   "makes it its zone file)")
    p.add_argument("--note", default="", help="free text for the log (default empty)")
    p.add_argument("--timeout", type=float, default=5.0,
                   help="s to wait for the monitor's answer (default 5)")
    add_monitor_key_arg(p)
    p.set_defaults(func=cmd_apply)


def cmd_apply(args: argparse.Namespace) -> int:
    from monitor import zones as zn
    from monitor.bus.session import default_instance, open_session
    from monitor.cases.zone_apply import apply_payload, request_apply
    from monitor.cli.monitor_key_arg import monitor_keys_of
    from monitor.cli.operator import first_status, operator_key_path, status_ignored_line
    from monitor.cli.roles import no_answer, role_keys
    from monitor.cli.zenoh_args import bounded as _bounded
    from monitor.cli.zenoh_args import bus_config as _bus_config
    from monitor.cli.zenoh_args import nothing_found_hint as _nothing_found_hint
    from monitor.signals import Interrupted, StopSignals, call_interruptible
    from monitor.wire.answers import ignored_text
    from monitor.wire.signing import load_private_key

    with StopSignals(name="monitor zones apply") as stop:
        bus = _bus_config(args, instance=args.instance or default_instance("zones-apply"))
        keys = role_keys(bus, args.role)
        key_path = operator_key_path(args)
        signer = load_private_key(key_path) if key_path else None
        if signer is None:
            print(f"monitor zones apply: no key for {args.operator} (--key): sending unsigned; "
                  "the monitor refuses it", file=sys.stderr, flush=True)
        if args.zones is not None:  # a broken file: its one line, nothing sent
            cell = zn.load_cell(args.zones)
        monitor_keys = monitor_keys_of(args, "monitor zones apply")
        ignored: list[str] = []  # answers not believed (--monitor-key): someone else's
        try:
            session = call_interruptible(lambda: open_session(bus), stop)
        except Interrupted:
            return 130
        with _bounded(session, "monitor zones apply") as session:
            started = time.monotonic()
            skipped: list[str] = []  # status answers not the monitor's (--monitor-key)
            status = first_status(session, keys, args.timeout, stop, monitor_keys, skipped)
            if (line := status_ignored_line("monitor zones apply", keys.status, skipped)):
                print(line, file=sys.stderr, flush=True)
            if status is None:
                if stop.is_set():
                    return 130
                raise no_answer("monitor zones apply", keys.status, args.timeout, bus, session,
                                stop, args.role)
            if args.zones is None:
                path = status.get("zones_file")
                if not path:
                    raise ConfigError("monitor zones apply: the monitor names no zone file in "
                                      "its status: give --zones FILE")
                cell = zn.load_cell(path)
            in_force = status.get("config_hash") or ""
            print(f"zone set in force {in_force[:12] or '(none)'}, file {cell.label}: "
                  f"{cell.config_hash}", file=sys.stderr, flush=True)
            payload = apply_payload(args.operator, cell.config_hash,
                                    cell=bus.cell if bus.prefix is None else "",
                                    boot=str(status.get("boot") or ""), note=args.note)
            signature = signer.sign(keys.zones_apply, payload) if signer else None
            left = max(0.1, args.timeout - (time.monotonic() - started))
            try:
                answer = call_interruptible(lambda: request_apply(
                    session, keys.zones_apply, payload, signature, left, monitor_keys,
                    ignored), stop)
            except Interrupted:
                return 130
    if answer is None:
        raise ConfigError(f"monitor zones apply: no monitor answered on {keys.zones_apply} "
                          f"within {args.timeout:g} s"
                          + (" (with an answer signed by --monitor-key)" if monitor_keys
                             else "")
                          + (f"; {ignored_text(ignored)}: someone else answers there"
                             if ignored else "") + f"; {_nothing_found_hint(bus)}")
    if ignored:
        print(f"monitor zones apply: {ignored_text(ignored)}: someone else answers on "
              f"{keys.zones_apply}", file=sys.stderr, flush=True)
    by = f"{args.role}: " if args.role else ""
    if answer["accepted"]:
        print(f"{by}zones applied by {args.operator}: {answer.get('reason', '')}")
        return 0
    print(f"{by}zone apply by {args.operator} REFUSED: {answer.get('reason', '')}")
    return 1
