"""``monitor case select SET`` (a signed zone set selection) and ``monitor zones set
add|list|show`` (the zone file's sets). docs/cases.md."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import yaml

from monitor import zones as zn
from monitor.cases.requests import case_payload
from monitor.cli.zone_files import read_zone_data, write_zone_data
from monitor.errors import ConfigError
from monitor.zones.settings import parse_moves, set_rules


def register(subparsers: argparse._SubParsersAction) -> None:
    from monitor.cli.keys import KEY_DIR
    from monitor.cli.monitor_key_arg import add_monitor_key_arg
    from monitor.cli.zenoh_args import add_zenoh_args as _add_zenoh_args

    parser = subparsers.add_parser("case", help="select the zone set the robot works in "
                                   "(signed; docs/cases.md)")
    sub = parser.add_subparsers(dest="case_action", metavar="ACTION", required=True)
    p = sub.add_parser("select", help="send a signed zone set selection; waits for the "
                       "monitor's answer",
                       description="Exit 0 verified (the switch follows the zone file's rules), "
                       "1 refused (reason printed), 2 no answer.")
    p.add_argument("set", help="zone set id, as in the zone file's sets")
    p.add_argument("--selector", required=True,
                   help="selector name, as in the monitor's selectors file (required)")
    p.add_argument("--key", metavar="FILE", help="the selector's private key (default "
                   f"{KEY_DIR}/<selector>.key)")
    p.add_argument("--seq", type=int, help="sequence number; must grow with every selection of "
                   "this selector (default: milliseconds since 1970)")
    p.add_argument("--timeout", type=float, default=3.0,
                   help="s to wait for the monitor's answer (default 3)")
    _add_zenoh_args(p, default_connect=True)
    add_monitor_key_arg(p)
    p.set_defaults(func=cmd_select)


def register_zone_sets(sub: argparse._SubParsersAction) -> None:
    """``monitor zones set ...`` (called by ``monitor.cli.zones``)."""
    parser = sub.add_parser("set", help="add, list or show the zone sets of a zone file")
    actions = parser.add_subparsers(dest="set_action", metavar="ACTION", required=True,
                                    help="add, list or show")
    p = actions.add_parser("add", help="add a zone set")
    p.add_argument("file", type=Path, help="zone file (YAML)")
    p.add_argument("id", help="set id")
    p.add_argument("--zones", required=True,
                   help="comma-separated ids of the protective and warning zones of the set "
                   "(required)")
    p.add_argument("--name", default="", help="display name (default none)")
    p.add_argument("--speed-scale", type=float,
                   help="speed cap of the set's warning zones while it applies (default none)")
    p.add_argument("--default", action="store_true",
                   help="make it the set in force at start (default: only for the first set)")
    p.set_defaults(func=cmd_set_add)
    p = actions.add_parser("list", help="list the zone sets and the switching rules")
    p.add_argument("file", type=Path, help="zone file (YAML)")
    p.set_defaults(func=cmd_set_list)
    p = actions.add_parser(
        "rules", help="set the switching rules: allowed transitions, switch-over time, "
        "default set, selector watch",
        description="Change the zone file's switching rules (docs/cases.md); options not "
        "given stay as they are. The file is validated before it is written.")
    p.add_argument("file", type=Path, help="zone file (YAML)")
    p.add_argument("--allow", action="append", metavar="FROM:TO",
                   help="an allowed switch (repeat); replaces the list of allowed switches "
                   "(default: the list stays)")
    p.add_argument("--any", action="store_true",
                   help="allow every switch (no transitions list; default off)")
    p.add_argument("--none", action="store_true",
                   help="allow no switch at all: the default set stays in force "
                   "(default off)")
    p.add_argument("--switch-over", type=float, metavar="S",
                   help="seconds both sets apply during a switch, 0-60 (default: unchanged)")
    p.add_argument("--default", dest="default_set", metavar="ID",
                   help="the set in force at start (default: unchanged)")
    p.add_argument("--selector-ttl", type=float, metavar="S",
                   help="a selection older than this is a fault: the selector must repeat it "
                   "(default: unchanged)")
    p.add_argument("--no-selector-ttl", action="store_true",
                   help="do not watch the selector (default off)")
    p.set_defaults(func=cmd_set_rules)
    p = actions.add_parser("show", help="show one zone set")
    p.add_argument("file", type=Path, help="zone file (YAML)")
    p.add_argument("id", help="set id")
    p.set_defaults(func=cmd_set_show)


def cmd_set_add(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    sets = data.get("sets") or []
    if any(isinstance(s, dict) and s.get("id") == args.id for s in sets):
        raise ConfigError(f"{args.file}: set '{args.id}' exists")
    entry: dict = {"id": args.id}
    if args.name:
        entry["name"] = args.name
    entry["zones"] = [z.strip() for z in args.zones.split(",") if z.strip()]
    if args.speed_scale is not None:
        entry["speed_scale"] = args.speed_scale
    data["sets"] = [*sets, entry]
    if args.default or not data.get("default_set"):
        data["default_set"] = args.id
    cell = write_zone_data(data, args.file)
    print(f"added set '{args.id}' ({len(entry['zones'])} zones); default set "
          f"{cell.spec.default_set}; config hash {cell.config_hash}")
    return 0


def cmd_set_rules(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    set_rules(data, parse_moves(args.allow) if args.allow else None, args.any, args.none,
              args.switch_over, args.default_set, args.selector_ttl, args.no_selector_ttl)
    write_zone_data(data, args.file)  # validates first: a fault writes nothing
    return cmd_set_list(args)


def cmd_set_list(args: argparse.Namespace) -> int:
    spec = zn.load_cell(args.file).spec
    if not spec.sets:
        print("no zone sets: every zone applies always")
        return 0
    for s in spec.sets:
        mark = "*" if s.id == spec.default_set else " "
        cap = f"  speed<={s.speed_scale:g}" if s.speed_scale is not None else ""
        print(f"{mark} {s.id}: {', '.join(s.zones)}{cap}" + (f"  ({s.name})" if s.name else ""))
    moves = ("any" if spec.transitions is None
             else ", ".join(f"{a}->{b}" for a, b in spec.transitions) or "none")
    ttl = f"{spec.selector_ttl_s:g} s" if spec.selector_ttl_s is not None else "not watched"
    print(f"default {spec.default_set}; transitions {moves}; switch-over "
          f"{spec.switch_over_s:g} s; selector ttl {ttl}")
    return 0


def cmd_set_show(args: argparse.Namespace) -> int:
    spec = zn.load_cell(args.file).spec
    found = next((s for s in spec.sets if s.id == args.id), None)
    if found is None:
        raise ConfigError(f"{args.file}: no set '{args.id}'")
    print(yaml.safe_dump(found.model_dump(mode="json", exclude_none=True),
                         sort_keys=False).rstrip())
    return 0


def cmd_select(args: argparse.Namespace) -> int:
    # the bus side (Zenoh, signing) only here: `monitor zones list` registers these commands too
    from monitor.bus.session import default_instance, open_session
    from monitor.cases.receiver import case_key, request_case
    from monitor.cli.keys import KEY_DIR
    from monitor.cli.monitor_key_arg import monitor_keys_of
    from monitor.cli.zenoh_args import bounded as _bounded
    from monitor.cli.zenoh_args import bus_config as _bus_config
    from monitor.cli.zenoh_args import nothing_found_hint as _nothing_found_hint
    from monitor.wire.answers import ignored_text
    from monitor.wire.signing import load_private_key

    bus = _bus_config(args, instance=args.instance or default_instance("case"))
    key = case_key(bus.key_prefix)
    key_path = Path(args.key) if args.key else (KEY_DIR / f"{args.selector}.key").expanduser()
    if not key_path.exists():
        raise ConfigError(f"monitor case select: no key for {args.selector} ({key_path}; "
                          "--key FILE): the monitor refuses unsigned selections")
    signer = load_private_key(key_path)
    monitor_keys = monitor_keys_of(args, "monitor case select")
    ignored: list[str] = []  # answers not believed (--monitor-key): someone else's
    seq = args.seq if args.seq is not None else int(time.time() * 1000)
    payload = case_payload(args.selector, args.set, seq,
                           cell=bus.cell if bus.prefix is None else "")
    with _bounded(open_session(bus), "monitor case select") as session:
        answer = request_case(session, key, payload, signer.sign(key, payload), args.timeout,
                              monitor_keys, ignored)
    if answer is None:
        print(f"monitor case select: no monitor answered on {key} within {args.timeout:g} s"
              + (" (with an answer signed by --monitor-key)" if monitor_keys else "")
              + (f"; {ignored_text(ignored)}: someone else answers there" if ignored else "")
              + f"; {_nothing_found_hint(bus)}", file=sys.stderr)
        return 2
    if ignored:
        print(f"monitor case select: {ignored_text(ignored)}: someone else answers on {key}",
              file=sys.stderr, flush=True)
    verdict = "verified" if answer["accepted"] else "REFUSED"
    print(f"zone set {args.set!r} by {args.selector} (seq {seq}) {verdict}: "
          f"{answer.get('reason', '')}")
    return 0 if answer["accepted"] else 1
