"""What the commissioning report says, gathered from files (I/O at this edge; the rendering in
``report`` is pure). Every value comes from an input file or is computed from one: no clock,
no host timing, so the same inputs give the same report and checksum. Host figures (capacity,
reaction time) come from a saved ``monitor status --json`` answer of the running service
(``--status FILE``), the host's own measurement; without one the report says "not given".
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

import cv2
import numpy as np

from monitor import __version__
from monitor.commission.cut_feet import hidden_feet_doubts
from monitor.commission.floor import zone_floors
from monitor.commission.pictures import camera_picture, floor_picture
from monitor.commission.walk_video import read_walk
from monitor.config import MonitorConfig, load_config
from monitor.detector.envelope import file_sha256, sidecar_path
from monitor.driver import protective_warning
from monitor.errors import InputError
from monitor.geometry import SeparationParams
from monitor.geometry.reaction import needed_separation_m
from monitor.health.references import (
    choose_references,
    load_chosen_reference,
    reference_warnings,
)
from monitor.service.commissioned import fingerprint, settings_changed
from monitor.service.setup import reaction_budget, zones_file_of
from monitor.wire.signing import key_fingerprint, load_operators, load_private_key, public_key_text
from monitor.zones import Cell, load_cell


def gather(config_path: Path | None, model_path: Path, walk_dir: Path | None = None,
           status_file: Path | None = None, by: str = "", date: str = "") -> dict:
    """The report's content (JSON-able, deterministic). ``model_path``: the model the config
    names (the synthetic model's file for a config without one)."""
    config = load_config(config_path)
    zones_file = zones_file_of(config)
    cell = load_cell(zones_file) if zones_file else None
    status = _read_json(status_file, "status file", " (save it with `monitor status --json "
                        "> FILE`)") if status_file else None
    walk = read_walk(walk_dir) if walk_dir else None
    base = config_path.parent if config_path else None
    print_ = fingerprint(config, cell.config_hash if cell else "", model_path)
    settings = settings_changed(config)
    content = {
        "product": {"name": "workcell-monitor", "version": __version__},
        "cell": config.bus.cell,
        "config": {"file": _name(config_path, base) if config_path else "embedded demo",
                   "sha256": file_sha256(config_path) if config_path else None},
        "fingerprint": print_,
        "model": _model(model_path, base),
        "zones": _zones(cell, zones_file, base),
        "settings": settings,
        "keys": _keys(config, base),
        "capacity": (status or {}).get("capacity"),
        "reaction": _reaction(config, cell, status),
        "walk": _walk(walk, walk_dir) if walk is not None else None,
        "warnings": _warnings(config, cell, status, walk, model_path),
        "signoff": {"commissioned_by": by, "date": date},
        "pictures": _pictures(config, cell),
        "sources": {"status": _name(status_file, base) if status_file else None,
                    "walk": _name(walk_dir, base) if walk_dir else None},
    }
    return content


def _name(path: Path, base: Path | None) -> str:
    """A path as the report prints it: relative to the config's folder when inside it (the
    same folder copied elsewhere gives the same report)."""
    path = Path(path).absolute()
    if base is not None:
        try:
            return str(path.relative_to(Path(base).absolute()))
        except ValueError:
            pass
    return path.name


def _read_json(path: Path, what: str, hint: str = "") -> dict:
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no such {what}") from None
    except (ValueError, UnicodeDecodeError):
        raise InputError(f"{path}: {what} is not JSON{hint}") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: {what} is not a JSON object")
    return data


def _model(model_path: Path, base: Path | None) -> dict:
    sidecar = sidecar_path(model_path)
    envelope = None
    if sidecar.is_file():
        try:
            envelope = json.loads(sidecar.read_text())
        except (ValueError, UnicodeDecodeError):
            envelope = {"error": f"{sidecar.name} is not JSON"}
        if isinstance(envelope, dict):  # the measured recall table is long: the limits only
            envelope = {k: v for k, v in envelope.items() if k not in ("recall", "absolute")}
    return {"file": _name(model_path, base), "sha256": file_sha256(model_path),
            "envelope": envelope, "envelope_file": sidecar.name if sidecar.is_file() else None}


def _zones(cell: Cell | None, zones_file: str | None, base: Path | None) -> dict | None:
    if cell is None:
        return None
    return {"file": _name(Path(zones_file), base), "sha256": file_sha256(Path(zones_file)),
            "config_hash": cell.config_hash,
            "cameras": [{"id": c.id, "size": f"{c.width}x{c.height}",
                         "calibrated": c.id in cell.camera_models}
                        for c in cell.cameras.values()],
            "zones": [{"id": z.id, "kind": z.kind, "shape": getattr(z, "shape", "polygon"),
                       "enabled": bool(z.enabled)} for z in cell.zones]}


def _key_id(text: str) -> str:
    """A short fingerprint of a public key text (SHA-256, first 16 hex digits)."""
    return key_fingerprint(text)


def _keys(config: MonitorConfig, base: Path | None) -> dict:
    bus = config.bus
    monitor_key = None
    if bus.signing_key:
        text = load_private_key(bus.signing_key).public_text
        monitor_key = {"public_key": text, "fingerprint": _key_id(text)}
    operators = []
    if bus.operators_file:
        for name, key in sorted(load_operators(bus.operators_file).items()):
            text = public_key_text(key)
            operators.append({"operator": name, "fingerprint": _key_id(text)})
    return {"monitor": monitor_key, "operators": operators,
            "unsigned_resets": bool(bus.allow_unsigned_resets)}


def _reaction(config: MonitorConfig, cell: Cell | None, status: dict | None) -> dict:
    """T_r as configured, as measured (the status's reaction budget, per camera) and the S_p
    each implies at the zone file's programmed speed."""
    t_r = reaction_budget(config).total_s()
    # the zone file's separation parameters as the pipeline uses them (defaults without)
    params = cell.prepared.separation if cell is not None else SeparationParams()
    speed = cell.spec.separation.programmed_speed_mps if cell is not None else 1.0
    measured = {}
    budget = (status or {}).get("reaction_budget") or {}
    for cam, figures in sorted((budget.get("cameras") or {}).items()):
        if isinstance(figures, dict) and isinstance(figures.get("measured_s"), int | float):
            m = float(figures["measured_s"])
            measured[cam] = {"measured_s": m, "s_p_m": round(needed_separation_m(
                params, speed, m), 4), "exceeded": bool(figures.get("exceeded"))}
    return {"configured_s": round(t_r, 4), "programmed_speed_mps": speed,
            "s_p_configured_m": round(needed_separation_m(params, speed, t_r), 4),
            "measured": measured}


def _walk(walk: dict, walk_dir: Path) -> dict:
    pictures = {}
    for name, file in sorted((walk.get("pictures") or {}).items()):
        path = Path(walk_dir) / str(file)
        if path.is_file():
            pictures[name] = base64.b64encode(path.read_bytes()).decode()
    return {**{k: v for k, v in walk.items() if k != "pictures"}, "pictures": pictures}


def _warnings(config: MonitorConfig, cell: Cell | None, status: dict | None,
              walk: dict | None, model_path: Path) -> list[str]:
    out = []
    warning = protective_warning(cell)
    if warning:
        out.append(warning)
    out += [f"zone file: {w}" for w in (cell.warnings if cell else ())]
    out += reference_warnings(config, cell)
    if config.bus.allow_unsigned_resets:
        out.append("resets are accepted without an operator key")
    if status is None:
        out.append("no status of the running service given (--status): capacity and the "
                   "measured reaction time are not in this report")
    else:
        out += [f"capacity: {w}" for w in (status.get("capacity") or {}).get("warnings", [])]
        if (status.get("reaction_budget") or {}).get("exceeded"):
            out.append("the measured reaction time exceeds the configured T_r")
    if walk is None:
        out.append("no walk test given (--walk): coverage and times to STOP are not shown")
    else:
        if walk.get("zones_hash") != (cell.config_hash if cell else ""):
            out.append("the walk test was made with other zones than these")
        out += hidden_feet_doubts(walk)
        for z in walk.get("zones", []):
            if z.get("kind") == "protective" and z.get("blind_spots"):
                out.append(f"zone {z['zone_id']}: {len(z['blind_spots'])} floor cells no "
                           "camera sees (blind spots)")
            for e in z.get("entries", []):
                if z.get("kind") == "protective" and e.get("stop_s") is None:
                    out.append(f"zone {z['zone_id']}: entry at {e['entry_s']} s without a "
                               "STOP")
            for c in z.get("corners", []) if z.get("kind") == "protective" else []:
                x, y = c["corner_m"]
                if not c.get("frames_seen"):
                    out.append(f"zone {z['zone_id']}: corner ({x:g}, {y:g}) m: no person seen "
                               "there in the walk (crouch there)")
                elif c.get("frames_near") and c["frames_seen"] < c["frames_near"]:
                    out.append(f"zone {z['zone_id']}: corner ({x:g}, {y:g}) m: the person was "
                               f"seen in {c['frames_seen']} of the {c['frames_near']} frames "
                               "they were there")
    if not sidecar_path(model_path).is_file():
        out.append("the model has no measured envelope (monitor model envelope)")
    return out


def _pictures(config: MonitorConfig, cell: Cell | None) -> dict[str, str]:
    """Every zone on each camera's reference image (a grey canvas where there is none) and
    on the floor plan (cell coordinates), PNG in base64."""
    if cell is None:
        return {}
    floors = zone_floors(cell)
    out = {"floor plan": base64.b64encode(floor_picture(cell, floors, None)).decode()}
    choices = choose_references(config, cell)
    for camera_id, cam in sorted(cell.cameras.items()):
        choice = choices.get(camera_id)
        image = load_chosen_reference(choice, cell) if choice is not None else None
        if image is None:
            image = np.full((cam.height, cam.width, 3), 96, np.uint8)
            cv2.putText(image, f"{camera_id}: no reference image", (20, 40),
                        cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 2, cv2.LINE_AA)
        png = camera_picture(image, cell, camera_id, floors, None)
        out[f"camera {camera_id}"] = base64.b64encode(png).decode()
    return out
