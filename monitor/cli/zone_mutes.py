"""``monitor zones mute FILE ZONE ...``: who may mute a zone, for how long, and what it is while
muted (the zone's ``mute:`` section, docs/muting.md), without editing YAML by hand. The file is
validated before it is written: a fault writes nothing."""

from __future__ import annotations

import argparse
from pathlib import Path

from monitor.cli.zone_files import read_zone_data, write_zone_data
from monitor.errors import ConfigError


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
    zone = next((z for z in data.get("zones") or []
                 if isinstance(z, dict) and z.get("id") == args.id), None)
    if zone is None:
        raise ConfigError(f"{args.file}: no zone '{args.id}'")
    allow = [v is not None for v in (args.operators, args.max_s, args.as_, args.speed_scale)]
    if sum((any(allow), args.unmutable, args.remove)) > 1:
        raise ConfigError("zones mute: give either --operators/--max-s (allow), --unmutable or "
                          "--remove")
    if not any(allow) and not args.unmutable and not args.remove:
        print(f"{args.id}: {describe(zone)}")
        return 0
    if args.unmutable:
        zone.pop("mute", None)
        zone["unmutable"] = True
    elif args.remove:
        zone.pop("mute", None)
        zone.pop("unmutable", None)
    else:
        mute = dict(zone.get("mute") or {})
        if args.operators is not None:
            mute["operators"] = [o.strip() for o in args.operators.split(",") if o.strip()]
        if args.max_s is not None:
            mute["max_s"] = args.max_s
        if args.as_ is not None:
            mute["as"] = args.as_
        if args.speed_scale is not None:
            mute["speed_scale"] = args.speed_scale
        missing = [f"--{k.replace('_', '-')}" for k in ("operators", "max_s") if k not in mute]
        if missing:
            raise ConfigError(f"zones mute: {args.id} has no mute rule yet: give "
                              f"{' and '.join(missing)}")
        zone.pop("unmutable", None)
        zone["mute"] = mute
    cell = write_zone_data(data, args.file)  # validates first: a fault writes nothing
    print(f"{args.id}: {describe(zone)}; config hash {cell.config_hash}")
    return 0


def describe(zone: dict) -> str:
    """The zone's mute rule in one line, as written in the file."""
    mute = zone.get("mute")
    if mute:
        what = "checked as nothing" if mute.get("as") == "none" else \
            f"checked as a warning zone (speed {mute['speed_scale']:g})" \
            if mute.get("speed_scale") is not None else "checked as a warning zone"
        return (f"may be muted by {', '.join(mute.get('operators') or [])} for at most "
                f"{mute.get('max_s'):g} s, {what}")
    if zone.get("unmutable"):
        return "never muted (unmutable)"
    return "no mute rule: " + ("never muted" if zone.get("kind") == "protective"
                               else "cannot be muted")
