"""Which reference image a camera's health checks start from: the zone file's or monitor.toml's.

A camera's reference (``monitor reference capture``; the "moved" and "defocused" checks and the
watch zones' backgrounds start from it) may be named in two places: the zone file's camera entry
(``reference:``, relative to the zone file, set with ``monitor zones camera set --reference``)
and monitor.toml's ``[[camera]] reference`` (relative to the config). The zone file wins: it is
where the camera's size, calibration and zones are, and it is what the integrator edits with
``monitor zones camera``. Both set and naming different files is legal (a config written before
the zone file knew references) but doubtful: the service says so at start.

A zone file's reference must have the camera's size exactly (``zones camera set`` checks it; the
service again at start, since the image may have been replaced since).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from monitor.errors import ConfigError

ZONE_FILE = "zone file"
CONFIG = "monitor.toml"


@dataclass(frozen=True)
class ReferenceChoice:
    """The reference a camera uses (None: none, the first sound frame takes its place), where
    it is named (``ZONE_FILE``, ``CONFIG`` or "none") and a doubt to log at start."""

    camera_id: str
    path: Path | None
    named_in: str
    warning: str | None = None


def zone_file_reference(cell, camera_id: str) -> Path | None:
    """The zone file's reference of a camera, resolved against the zone file's folder."""
    if cell is None or camera_id not in cell.cameras:
        return None
    ref = cell.cameras[camera_id].reference
    if ref is None:
        return None
    base = cell.path.parent if cell.path is not None else Path.cwd()
    return Path(os.path.normpath(base / ref))


def choose_reference(camera_id: str, config_reference: str | None, cell) -> ReferenceChoice:
    """The zone file's reference when it names one, monitor.toml's otherwise. Pure (paths are
    compared as written, made absolute; no file is read)."""
    zone_ref = zone_file_reference(cell, camera_id)
    config_ref = Path(os.path.normpath(os.path.abspath(config_reference))) \
        if config_reference else None
    if zone_ref is None:
        return ReferenceChoice(camera_id, config_ref, CONFIG if config_ref else "none")
    warning = None
    if config_ref is not None and config_ref != zone_ref:
        warning = (f"camera {camera_id}: the zone file's reference {zone_ref} is used; "
                   f"monitor.toml's [[camera]] reference {config_ref} differs and is ignored "
                   "(remove it from monitor.toml)")
    return ReferenceChoice(camera_id, zone_ref, ZONE_FILE, warning)


def choose_references(config, cell) -> dict[str, ReferenceChoice]:
    """Every configured camera's reference (see ``choose_reference``)."""
    return {c.id: choose_reference(c.id, c.reference, cell) for c in config.cameras}


def reference_warnings(config, cell) -> list[str]:
    """The start-up doubts: cameras whose two references differ."""
    return [c.warning for c in choose_references(config, cell).values() if c.warning]


def without_reference(config, cell) -> list[str]:
    """Real cameras (any source but ``synthetic:``) without a reference image."""
    chosen = choose_references(config, cell)
    return [c.id for c in config.cameras
            if chosen[c.id].path is None and not str(c.source).startswith("synthetic:")]


def missing_reference_warnings(config, cell) -> list[str]:
    """One line per real camera without a reference: what it is not judged by then."""
    return [f"camera {cid}: no reference image: glare and the detector's image conditions are "
            "judged by the model envelope's absolute limits, not this camera's normal view, "
            "and a camera already moved, blurred or changed at start is not seen (take one "
            "with 'monitor reference capture', name it with 'monitor zones camera set "
            "--reference')" for cid in without_reference(config, cell)]


def load_chosen_reference(choice: ReferenceChoice, cell) -> np.ndarray | None:
    """Read the chosen image; a zone file's must have the camera's size (one-line error)."""
    from monitor.health import load_reference

    if choice.path is None:
        return None
    image = load_reference(choice.path)
    if choice.named_in == ZONE_FILE:
        cam = cell.cameras[choice.camera_id]
        require_size(image, cam.width, cam.height, f"{cell.label}: camera '{cam.id}' reference "
                     f"{choice.path}")
    return image


def require_size(image: np.ndarray, width: int, height: int, what: str) -> None:
    """A reference of exactly the camera's size, else a one-line ConfigError."""
    h, w = image.shape[:2]
    if (w, h) != (width, height):
        raise ConfigError(f"{what} is {w}x{h}, the camera is {width}x{height} (capture it "
                          "again with 'monitor reference capture')")
