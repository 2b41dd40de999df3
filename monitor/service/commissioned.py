"""Which commissioned configuration runs: the fingerprint of a configuration and the signed record
``monitor commission report`` leaves beside the config file (``commissioned.json``).

The fingerprint is everything that decides safety: the zone set (``config_hash``, the one every
command names), the model file (SHA-256), the settings that differ from the defaults (SHA-256 of
their canonical JSON), and the SHA-256 of every file the config names (``schema.config_files``:
operators, selectors and commissioners files, keys, the Zenoh config and TLS files, reference
images, the self-test image, handover peers' keys) plus the model's envelope and the zone
file's reference images. A file named but absent digests as ``"missing"``.

The record is signed over every byte (``monitor.wire.evidence``) with a commissioner's Ed25519
key and names the report it belongs to by the report's SHA-256. ``status_of`` accepts a record
only when its signature is valid and its key is listed in ``[service] commissioners_file``; it
answers the status's ``commissioned: {checksum, by, key, matches, differs, reason}`` and
``differs`` names each part or file that is not the recorded one (``bus.operators_file``,
``zones``, ...). No record, a forged or foreign one: ``matches`` false with the reason.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import Any

from monitor.config import CameraConfig, MonitorConfig, load_config
from monitor.detector.envelope import file_sha256, sidecar_path
from monitor.errors import ConfigError
from monitor.health.references import zone_file_reference
from monitor.schema import config_files
from monitor.wire.evidence import Layout, NotSigned, open_signed, sign
from monitor.wire.signing import Signer, key_fingerprint, load_operators

RECORD_NAME = "commissioned.json"
PARTS = ("zones_hash", "model_sha256", "settings_sha256")
RECORD_FORMAT = "workcell.commissioned/2"
# {"record": {...}, "key": "ed25519:...", "signature": "..."}: the block by position at the end
RECORD_LAYOUT = Layout("commissioned-record", b',\n "key": "', b'",\n "signature": "',
                       b'"\n}\n')
# files the config names that are fingerprinted otherwise (the model and the zone set by their
# own digests) or are not inputs (the recorder's output folder)
NOT_INPUTS = frozenset({"model.path", "zones.file", "recorder.data_dir"})
MISSING = "missing"


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


def safety_files(config: MonitorConfig, cell, model_path: str | Path) -> dict[str, Path]:
    """Every input file that decides what the monitor does, by the name ``status`` shows."""
    out = {k: Path(v) for k, v in config_files(config).items() if k not in NOT_INPUTS}
    out["model envelope"] = sidecar_path(model_path)
    for camera_id in sorted(cell.cameras) if cell is not None else ():
        ref = zone_file_reference(cell, camera_id)
        if ref is not None:
            out[f"zone file camera {camera_id} reference"] = ref
    return dict(sorted(out.items()))


def file_digest(path: Path) -> str:
    """SHA-256 of a file; ``"missing"`` when there is none (a named file removed is a
    change, and one added later is one too)."""
    try:
        return file_sha256(path)
    except FileNotFoundError:
        return MISSING
    except OSError as exc:
        return f"unreadable ({exc.strerror})"


def file_digests(files: dict[str, Path]) -> dict[str, str]:
    return {name: file_digest(path) for name, path in files.items()}


def fingerprint(config: MonitorConfig, zones_hash: str, model_path: str | Path, cell=None,
                model_sha256: str | None = None) -> dict:
    """The digests of a running (or reported) configuration. ``model_sha256``: the running
    model's, taken once at start (the file on disk may be replaced; what runs is what was
    loaded)."""
    return {"zones_hash": zones_hash,
            "model_sha256": model_sha256 or file_sha256(Path(model_path)),
            "settings_sha256": settings_digest(settings_changed(config)),
            "files": file_digests(safety_files(config, cell, model_path))}


def record_path(config_path: str | Path) -> Path:
    """Where the record of a config file lies: beside it."""
    return Path(config_path).parent / RECORD_NAME


def record_bytes(report: bytes, report_name: str, by: str, print_: dict,
                 signer: Signer) -> bytes:
    """The signed record of a report (``report``: the signed report file's bytes)."""
    body = {"format": RECORD_FORMAT, "report": report_name,
            "report_sha256": hashlib.sha256(report).hexdigest(), "by": by,
            **{k: print_[k] for k in PARTS}, "files": dict(sorted(print_["files"].items()))}
    text = '{\n "record": ' + json.dumps(body, indent=2, sort_keys=True).replace("\n", "\n ")
    return sign(text.encode(), RECORD_LAYOUT, signer)


def write_record(path: Path, data: bytes) -> None:
    """The record (atomic: written beside, then renamed, so a running monitor never reads
    half of one)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)


class RecordRefused(Exception):
    """The record is not accepted (the message says why, for the status)."""


def read_record(path: Path, commissioners: dict) -> tuple[dict, str, str]:
    """(the record, its commissioner's name, their key's fingerprint) when its signature is
    valid and made by a key in ``commissioners``; ``RecordRefused`` otherwise."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise RecordRefused(f"no {path.name} beside the config: not commissioned") from None
    except OSError as exc:
        raise RecordRefused(f"{path}: unreadable ({exc.strerror})") from None
    try:
        opened = open_signed(data, RECORD_LAYOUT)
    except NotSigned as exc:
        raise RecordRefused(f"{path.name} is not signed ({exc}): refused") from None
    fp = key_fingerprint(opened.key_text)
    if not opened.valid:
        raise RecordRefused(f"{path.name}: its signature does not match its content "
                            "(changed after it was signed): refused")
    name = next((n for n, k in commissioners.items() if k == opened.key), None)
    if name is None:
        raise RecordRefused(f"{path.name} is signed by key {fp}, which is not listed in the "
                            "commissioners file: refused")
    try:
        record = json.loads(data)["record"]
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        raise RecordRefused(f"{path.name}: not a record") from None
    if not isinstance(record, dict) or record.get("format") != RECORD_FORMAT:
        raise RecordRefused(f"{path.name}: not a {RECORD_FORMAT} record")
    return record, name, fp


def load_commissioners(config: MonitorConfig) -> dict:
    """The commissioners file's keys; ``RecordRefused`` without one (nobody can commission)."""
    path = config.service.commissioners_file
    if not path:
        raise RecordRefused("no [service] commissioners_file: no commissioned record is "
                            "accepted")
    try:
        return load_operators(path, "commissioners file", "commissioner")
    except ConfigError as exc:
        raise RecordRefused(str(exc)) from None


def differences(record: dict, running: dict) -> list[str]:
    """The parts and files of ``running`` that are not the recorded ones, by name."""
    out = [k.split("_")[0] for k in PARTS if record.get(k) != running.get(k)]
    files, recorded = running.get("files") or {}, record.get("files") or {}
    out += [name for name in sorted(set(files) | set(recorded))
            if files.get(name) != recorded.get(name)]
    return out


def status_of(config_path: str | Path | None, running: dict,
              config: MonitorConfig | None = None) -> dict:
    """The status's ``commissioned`` field for the ``running`` fingerprint (``config``: the
    running one, for its commissioners file; read from ``config_path`` when not given)."""
    if config_path is None:
        return {"checksum": None, "matches": False,
                "reason": "embedded demo: no commissioned configuration"}
    path = record_path(config_path)
    if not path.exists():
        return {"checksum": None, "matches": False,
                "reason": f"no {RECORD_NAME} beside {Path(config_path).name}: not commissioned"}
    try:
        if config is None:
            config = load_config(config_path)
        record, name, fp = read_record(path, load_commissioners(config))
    except RecordRefused as exc:
        return {"checksum": None, "matches": False, "reason": str(exc)}
    differs = differences(record, running)
    out = {"checksum": record.get("report_sha256"), "by": name, "key": fp,
           "report": record.get("report"), "matches": not differs, "differs": differs}
    if differs:
        out["reason"] = ("not commissioned: " + ", ".join(differs)
                         + (" differs" if len(differs) == 1 else " differ")
                         + " from the commissioned record")
    return out
