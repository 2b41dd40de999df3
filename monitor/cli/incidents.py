"""`monitor incidents list|show|export`: read the incident recorder's index (read-only)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from monitor.errors import InputError


def _data_dir(args: argparse.Namespace) -> Path:
    from monitor.incidents import data_dir_of

    if args.dir is not None:
        path = args.dir
    else:
        from monitor.config import load_config

        path = data_dir_of(load_config(args.config).recorder)
    if not path.is_dir():
        raise InputError(f"{path}: no incident data directory (give --dir, or --config with "
                         f"[recorder] data_dir)")
    return path


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dir", type=Path, help="incident data directory (default: [recorder] "
                   "data_dir of --config, else $WORKCELL_MONITOR_HOME/incidents)")
    p.add_argument("--config", type=Path, help="monitor.toml whose [recorder] data_dir to read")


def _filters(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cause", help="only incidents with this cause (stop, latch, "
                   "reset_accepted, reset_refused, fault, alert) or an alert of this kind "
                   "(zone_muted, scene_change, ...)")
    p.add_argument("--hours", type=float, help="only the last HOURS hours (default: all)")
    p.add_argument("--limit", type=int, help="at most this many, newest first (default: all)")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("incidents", help="list, show and export recorded incidents")
    sub = p.add_subparsers(dest="incidents_command", metavar="ACTION", required=True)
    ls = sub.add_parser("list", help="one line per incident, newest first")
    _common(ls)
    _filters(ls)
    ls.add_argument("--json", action="store_true", help="JSON rows instead of a table")
    ls.set_defaults(func=cmd_list)
    show = sub.add_parser("show", help="one incident's record: events, commands, clips")
    _common(show)
    show.add_argument("id", help="the incident id (from 'monitor incidents list')")
    show.set_defaults(func=cmd_show)
    ex = sub.add_parser("export", help="CSV or JSON rows, or a zip with records and clips")
    _common(ex)
    _filters(ex)
    ex.add_argument("--format", choices=("csv", "json", "zip"), default="csv")
    ex.add_argument("--out", type=Path, help="output file (default: stdout; required for zip)")
    ex.set_defaults(func=cmd_export)


def _select(args: argparse.Namespace):
    from monitor.incidents import IncidentIndex

    since = time.time() - args.hours * 3600 if args.hours is not None else None
    return IncidentIndex(_data_dir(args)).list(since=since, cause=args.cause, limit=args.limit)


def cmd_list(args: argparse.Namespace) -> int:
    incidents = _select(args)
    if args.json:
        from monitor.incidents.export import to_json

        sys.stdout.write(to_json(incidents, records=False))
        return 0
    for i in incidents:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(i.wall))
        reset = "" if i.operator is None else \
            f"  reset by {i.operator}: {i.reset_message}"
        clips = len(i.clip_paths())
        print(f"{i.id}  {when}  {i.cause_text():<22} {i.describe}{reset}  "
              f"[{clips} clip{'s' if clips != 1 else ''}{'' if i.complete else ', recording'}]")
    if not incidents:
        print("no incidents")
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    from monitor.incidents import IncidentIndex

    incident = IncidentIndex(_data_dir(args)).get(args.id)
    if incident is None:
        raise InputError(f"no incident {args.id!r}")
    print(json.dumps(incident.record, indent=1))
    for camera, path in incident.clip_paths().items():
        print(f"clip {camera}: {path}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from monitor.incidents import export

    incidents = _select(args)
    if args.format == "zip":
        if args.out is None:
            raise InputError("--format zip needs --out FILE")
        clips = export.to_zip(incidents, args.out)
        print(f"{args.out}: {len(incidents)} incidents, {clips} clips")
        return 0
    text = export.to_csv(incidents) if args.format == "csv" else export.to_json(incidents)
    if args.out is None:
        sys.stdout.write(text)
    else:
        args.out.write_text(text)
    return 0
