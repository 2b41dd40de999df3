"""What the commissioning report says, gathered from files (I/O at this edge; the rendering in
``report`` is pure). Every value comes from an input file or is computed from one: no clock,
no host timing, so the same inputs give the same report and checksum. Host figures (capacity,
reaction time) come from a saved ``monitor status --json`` answer of the running service
(``--status FILE``), the host's own measurement; without one the report says "not given".
"""

from __future__ import annotations

import base64
import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from monitor import __version__
from monitor.commission import details
from monitor.commission.floor import zone_floors
from monitor.commission.open_warnings import Facts, open_warnings
from monitor.commission.pictures import camera_picture, floor_picture
from monitor.commission.unseen import unseen_regions
from monitor.commission.verdict import DEFAULT_LIMITS, WalkLimits, camera_verdicts, zone_verdicts
from monitor.commission.walk_video import read_walk
from monitor.config import MonitorConfig, load_config
from monitor.detector.envelope import file_sha256, sidecar_path
from monitor.errors import InputError
from monitor.geometry import SeparationParams
from monitor.geometry.reaction import needed_separation_m
from monitor.health.references import (
    choose_references,
    load_chosen_reference,
)
from monitor.service.commissioned import fingerprint, settings_changed
from monitor.service.setup import reaction_budget, zones_file_of
from monitor.wire.signing import key_fingerprint, load_operators, load_private_key, public_key_text
from monitor.zones import Cell, load_cell


def gather(config_path: Path | None, model_path: Path,
           walk_dirs: Sequence[Path] | Path | None = None,
           status_file: Path | None = None, by: str = "", date: str = "",
           signer_key: str | None = None, limits: WalkLimits = DEFAULT_LIMITS) -> dict:
    """The report's content (JSON-able, deterministic). ``model_path``: the model the config
    names (the synthetic model's file for a config without one); ``walk_dirs``: the walks (one
    per camera, or several passes: they merge); ``signer_key``: the public key text of the
    commissioner who signs it."""
    config = load_config(config_path)
    if limits.clear_time_s is None:  # the walk's gaps are judged against the config's policy
        limits = dataclasses.replace(limits, clear_time_s=config.policy.clear_time)
    zones_file = zones_file_of(config)
    cell = load_cell(zones_file) if zones_file else None
    status = _read_json(status_file, "status file", " (save it with `monitor status --json "
                        "> FILE`)") if status_file else None
    if isinstance(walk_dirs, str | Path):
        walk_dirs = [Path(walk_dirs)]
    walk_dirs = list(walk_dirs or [])
    walks = [read_walk(d) for d in walk_dirs]
    base = config_path.parent if config_path else None
    zone_details = details.zones(cell) if cell is not None else []
    reaction = _reaction(config, cell, status)
    selectors = sorted(load_operators(config.bus.selectors_file, "selectors file", "selector")
                       ) if config.bus.selectors_file else []
    current = [w for w in walks if w.get("zones_hash") == (cell.config_hash if cell else "")]
    facts = Facts(config, cell, status, walks, model_path, _is_test_model(model_path),
                  reaction, zone_details, limits)
    print_ = fingerprint(config, cell.config_hash if cell else "", model_path, cell)
    settings = settings_changed(config)
    content = {
        "product": {"name": "workcell-monitor", "version": __version__},
        "cell": config.bus.cell,
        "config": {"file": _name(config_path, base) if config_path else "embedded demo",
                   "sha256": file_sha256(config_path) if config_path else None},
        "fingerprint": print_,
        "model": _model(model_path, base, status),
        "zones": _zones(cell, zones_file, base),
        "settings": settings,
        "keys": _keys(config, base),
        "capacity": (status or {}).get("capacity"),
        "reaction": reaction,
        "walks": [_walk(w, d) for w, d in zip(walks, walk_dirs, strict=True)],
        "verdicts": {"zones": [v.to_dict() for v in zone_verdicts(zone_details, current,
                                                                  limits)],
                     "cameras": [v.to_dict() for v in camera_verdicts(
                         sorted(cell.cameras) if cell else [], current)],
                     "min_walked": limits.min_walked},
        "zone_details": zone_details,
        "zone_sets": details.zone_sets(cell, selectors) if cell is not None else None,
        "calibration": details.calibrations(cell) if cell is not None else [],
        "person": details.person_and_separation(cell) if cell is not None else None,
        "budget": _budget(config),
        "not_tested": _not_tested(walks, cell),
        "warnings": open_warnings(facts),
        "signoff": {"commissioned_by": by, "date": date,
                    "key": {"public_key": signer_key, "fingerprint": _key_id(signer_key)}
                    if signer_key else None},
        "pictures": _pictures(config, cell),
        # floor of the protective/warning zones no camera sees: its cost, what would see it
        "unseen": unseen_regions(cell) if cell is not None else [],
        "sources": {"status": _name(status_file, base) if status_file else None,
                    "walks": [_name(d, base) for d in walk_dirs]},
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


def _model(model_path: Path, base: Path | None, status: dict | None = None) -> dict:
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
            "envelope": envelope, "envelope_file": sidecar.name if sidecar.is_file() else None,
            "backend": _backend((status or {}).get("detector"))}


def _backend(detector: object) -> dict | None:
    """What runs the model in the service whose status was given (``Choice.to_dict``): the
    backend, its precision and how its persons agree with onnxruntime's; None without one."""
    if not isinstance(detector, dict):
        return None
    return {k: detector.get(k) for k in ("backend", "precision", "agreement", "reason")}


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


def _budget(config: MonitorConfig) -> dict:
    """T_r of this configuration, part by part (``ReactionBudget``)."""
    budget = reaction_budget(config)
    return {**{k: round(v, 4) for k, v in dataclasses.asdict(budget).items()},
            "total_s": round(budget.total_s(), 4)}


def _is_test_model(model_path: Path) -> bool:
    """The synthetic test model (its metadata says so, as the detector reads it)."""
    try:
        session = ort.InferenceSession(str(model_path), providers=["CPUExecutionProvider"])
    except Exception:  # a broken model is the detector's error at start, not the report's
        return False
    return "synthetic_weights" in (session.get_modelmeta().custom_metadata_map or {})


def _not_tested(walks: list[dict], cell: Cell | None) -> list[str]:
    """What this commissioning did not test and what the monitor cannot see."""
    out = ["the monitor's own processing, the bus and the robot controller are not in the "
           "walk's time to STOP: they are the reaction budget, measured by the running service",
           "persons other than the walker: smaller or crouching persons, several at once, "
           "unusual clothing, carried objects",
           "lighting other than during the walk (night, sun through windows, a lamp out)",
           "space no camera sees (the blind spots, the floor behind occluders and the robot): "
           "the monitor treats it as occupied only where the zone file says so",
           "the robot's own motion and the separation distance in operation (no pose during "
           "the walk test)"]
    if not any(w.get("truth") for w in walks):
        out.append("detection delay: without ground truth an entry starts at the first "
                   "detection, so the frames a detector missed before it are not timed")
    for w in walks:
        for z in w.get("zones", []):
            if z.get("unvisited"):
                out.append(f"zone {z['zone_id']}: {len(z['unvisited'])} visible floor cells "
                           f"the walk never saw a person on (walk {w.get('video')})")
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
