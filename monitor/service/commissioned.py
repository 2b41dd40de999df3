"""Which commissioned configuration runs: the fingerprint of a configuration and the record
``monitor commission report`` leaves beside the config file (``commissioned.json``).

The fingerprint of what runs is three digests: the zone set (``config_hash``, the one every
command names), the model file (SHA-256) and the settings that differ from the defaults
(SHA-256 of their canonical JSON). The report prints them and its own checksum; the record
keeps them. ``monitor run`` reads the record at start and answers in its status
``commissioned: {checksum, by, matches, differs}``; a signed zone apply is compared again
(``matches`` false, ``differs: ["zones"]``). No record: ``checksum`` null, ``matches`` false.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import Any

from monitor.config import CameraConfig, MonitorConfig
from monitor.detector.envelope import file_sha256

RECORD_NAME = "commissioned.json"
PARTS = ("zones_hash", "model_sha256", "settings_sha256")


def _plain(value: Any) -> Any:
    """JSON-able: tuples as lists, paths and other objects as text."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if value is None or isinstance(value, bool | int | float | str):
        return value
    return str(value)


def _flat(prefix: str, value: Any, default: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict) and isinstance(default, dict):
        for key in sorted(set(value) | set(default)):
            _flat(f"{prefix}.{key}" if prefix else key, value.get(key), default.get(key), out)
    elif _plain(value) != _plain(default):
        out[prefix] = _plain(value)


def settings_changed(config: MonitorConfig) -> dict[str, Any]:
    """Every setting of ``config`` that differs from its default, as ``section.key: value``
    (cameras as ``camera[<id>].key``), sorted by name."""
    out: dict[str, Any] = {}
    data = dataclasses.asdict(config)
    defaults = dataclasses.asdict(MonitorConfig())
    for name in sorted(data):
        if name in ("cameras", "source_file"):
            continue
        _flat(name, data[name], defaults[name], out)
    plain_camera = dataclasses.asdict(CameraConfig())
    for cam in config.cameras:
        _flat(f"camera[{cam.id}]", dataclasses.asdict(cam), plain_camera, out)
    return dict(sorted(out.items()))


def settings_digest(settings: dict[str, Any]) -> str:
    return hashlib.sha256(canonical(settings)).hexdigest()


def canonical(value: Any) -> bytes:
    """The one byte form that digests are taken of (sorted keys, no spaces)."""
    return json.dumps(_plain(value), sort_keys=True, separators=(",", ":")).encode()


def fingerprint(config: MonitorConfig, zones_hash: str, model_path: str | Path) -> dict:
    """The three digests of a running (or reported) configuration."""
    return {"zones_hash": zones_hash, "model_sha256": file_sha256(Path(model_path)),
            "settings_sha256": settings_digest(settings_changed(config))}


def record_path(config_path: str | Path) -> Path:
    """Where the record of a config file lies: beside it."""
    return Path(config_path).parent / RECORD_NAME


def write_record(path: Path, checksum: str, print_: dict, report_name: str, by: str) -> None:
    """The record (atomic: written beside, then renamed)."""
    body = {"checksum": checksum, "report": report_name, "by": by,
            **{k: print_[k] for k in PARTS}}
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(body, indent=1, sort_keys=True) + "\n")
    tmp.replace(path)


def status_of(config_path: str | Path | None, running: dict) -> dict:
    """The status's ``commissioned`` field for the ``running`` fingerprint."""
    if config_path is None:
        return {"checksum": None, "matches": False,
                "reason": "embedded demo: no commissioned configuration"}
    path = record_path(config_path)
    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        return {"checksum": None, "matches": False,
                "reason": f"no {RECORD_NAME} beside {Path(config_path).name}: not commissioned"}
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        return {"checksum": None, "matches": False, "reason": f"{path}: unreadable ({exc})"}
    if not isinstance(record, dict) or not isinstance(record.get("checksum"), str):
        return {"checksum": None, "matches": False, "reason": f"{path}: not a record"}
    differs = [k.split("_")[0] for k in PARTS if record.get(k) != running.get(k)]
    return {"checksum": record["checksum"], "by": record.get("by"),
            "report": record.get("report"), "matches": not differs, "differs": differs}
