"""What the zone-file commands share (``monitor zones ...``, ``zone_calibrate``,
``zone_cameras``, ``cases``, ``reference``): reading a zone file for an edit, writing it back
validated, number arguments, the camera an image polygon belongs to, help texts that name
their defaults. One module below all of them, so none imports another's helpers."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

from monitor import zones as zn
from monitor.errors import ConfigError
from monitor.zones.cameras import choose_camera, zone_file_hint


def read_zone_data(path: Path) -> dict:
    data = zn.read_cell_document(path)  # edits keep the file's comments and layout
    zn.parse_cell(data, path)  # refuse to edit a file that is already invalid
    return data


def write_zone_data(data: dict, path: Path) -> zn.Cell:
    cell = zn.write_cell_data(data, path)  # validates first: a fault writes nothing
    for w in cell.warnings:
        print(f"monitor: warning: {path}: {w}", file=sys.stderr)
    return cell


def numbers(text: str, count: int | None, what: str) -> list[float]:
    parts = [p for p in re.split(r"[,\s]+", text.strip()) if p]
    try:
        out = [float(p) for p in parts]
    except ValueError:
        raise ConfigError(f"{what}: cannot read numbers from {text!r}") from None
    if not all(np.isfinite(out)):
        raise ConfigError(f"{what}: numbers must be finite in {text!r}")
    if count is not None and len(out) != count:
        raise ConfigError(f"{what}: expected {count} numbers, got {len(out)} in {text!r}")
    return out


def camera_for(data: dict, args: argparse.Namespace) -> str:
    """The camera of an image polygon: --camera, or the file's only camera (one rule for
    every command: monitor.zones.cameras)."""
    cams = [c.get("id") for c in data.get("cameras") or [] if isinstance(c, dict)]
    return choose_camera(cams, args.camera, str(args.file),
                         zone_file_hint(args.file, args.camera or "ID"))


def plural(n: int, noun: str) -> str:
    """'1 camera', '2 cameras'."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


_POSITIONAL_HELP = {"file": "zone file (YAML)", "id": "zone id", "ids": "zone ids"}


def document_defaults(parser: argparse.ArgumentParser, none_text: str) -> None:
    """Every option says its default in --help (and every argument has a help text)."""
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if action.help is None:
            action.help = _POSITIONAL_HELP.get(action.dest, action.dest.replace("_", " "))
        if not action.option_strings or "default" in action.help:
            continue
        if action.required:
            action.help += " (required)"
        elif isinstance(action, argparse._StoreTrueAction):
            action.help += " (default: off)"
        elif action.default in (None, []):
            action.help += f" (default: {none_text})"
        else:
            action.help += " (default: %(default)s)"
