"""``monitor zones mute FILE ZONE ...``: who may mute a zone, for how long, and what it is while
muted (the zone's ``mute:`` section, docs/muting.md), without editing YAML by hand. The file is
validated before it is written: a fault writes nothing."""

from __future__ import annotations

import argparse
from pathlib import Path

from monitor.cli.zone_files import read_zone_data, write_zone_data
from monitor.zones.settings import describe_mute, find_zone, set_mute


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "mute", help="allow muting a zone (who, how long, as what), forbid it, or show it",
        description="Set the zone's mute section: --operators and --max-s allow a mute; "
        "--unmutable forbids it; --remove drops the section (a protective zone without one "
        "is unmutable). Without an option it shows the zone's mute rule.")
    p.add_argument("file", type=Path, help="zone file (YAML)")
    p.add_argument("id", help="zone id")
    p.add_argument("--operators", help="comma-separated operators (names of the operators "
                   "file) allowed to mute the zone (default: as in the file)")
    p.add_argument("--max-s", type=float, help="the longest mute one request may ask for, "
                   "seconds, at most 3600 (default: as in the file)")
    p.add_argument("--as", dest="as_", choices=("warning", "none"),
                   help="what the muted zone is checked as (default warning: a person inside "
                   "SLOWs)")
    p.add_argument("--speed-scale", type=float,
                   help="SLOW scale of the muted zone checked as a warning zone (default: the "
                   "slowest warning zone scale of the file)")
    p.add_argument("--unmutable", action="store_true",
                   help="the zone may never be muted (default off)")
    p.add_argument("--remove", action="store_true",
                   help="drop the zone's mute section (default off)")
    p.set_defaults(func=cmd_mute)


def cmd_mute(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    zone = find_zone(data, args.id, str(args.file))
    operators = args.operators.split(",") if args.operators is not None else None
    if not set_mute(zone, operators, args.max_s, args.as_, args.speed_scale, args.unmutable,
                    args.remove):
        print(f"{args.id}: {describe(zone)}")
        return 0
    cell = write_zone_data(data, args.file)  # validates first: a fault writes nothing
    print(f"{args.id}: {describe(zone)}; config hash {cell.config_hash}")
    return 0


describe = describe_mute  # the zone's mute rule in one line (monitor.zones.settings)
