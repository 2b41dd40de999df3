"""Zone editing for the console: the same rules as ``monitor zones``.

Every save reads the file as a round-trip document (comments, key order and indentation kept),
changes one zone, validates the WHOLE file (``monitor.zones.parse_cell``: a self-intersecting
polygon, a point outside the image, a warning zone without speed_scale ... are refused with the
one-line message ``monitor zones`` prints) and only then writes it atomically, keeping the
previous file as FILE.bak (``monitor.zones.write_cell_data``). A save names the file version it
edited (``base``, the sha256 of the bytes the page loaded): when the file changed since, the
save is refused instead of silently undoing someone else's edit.

The running ``monitor run`` does not pick the change up: it loads the zone file once at start,
and the zone set in force is the ``config_hash`` of every command; the console shows both.
"""

from __future__ import annotations

import hashlib
import math
import threading
from pathlib import Path
from typing import Any

import numpy as np

from monitor import zones as zn
from monitor.errors import ConfigError
from monitor.zones.draw import volume_outline_m
from monitor.zones.schema import PolygonZone

EDITABLE_KINDS = ("protective", "warning", "mask", "watch", "occluder")
MAX_POINTS = 1000


def file_sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class ZoneEditor:
    """The zone file the console shows and edits; saves are serialised."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.lock = threading.Lock()  # every save of the file, by any editor
        self._cached: tuple[str, zn.Cell] | None = None
        self.cell()  # a broken zone file stops the console's start, with its one line

    def cell(self) -> zn.Cell:
        """The file as it is on disk now (parsed again only when its bytes changed)."""
        sha = file_sha(self.path)
        cached = self._cached
        if cached is not None and cached[0] == sha:
            return cached[1]
        cell = zn.load_cell(self.path)
        self._cached = (sha, cell)
        return cell

    def editor_data(self) -> dict:
        """Cameras, image polygons (editable) and the floor footprints of volumes, in pixels
        of each camera (shown, not edited here)."""
        cell = self.cell()
        cams = [{"id": c.id, "width": c.width, "height": c.height,
                 "calibrated": c.id in cell.camera_models} for c in cell.cameras.values()]
        polygons, footprints = [], []
        for z in cell.zones:
            if isinstance(z, PolygonZone):
                polygons.append({"id": z.id, "name": z.name, "kind": z.kind, "camera": z.camera,
                                 "enabled": z.enabled, "speed_scale": z.speed_scale,
                                 "points_px": [list(p) for p in z.points_px]})
                continue
            for cam_id, model in cell.camera_models.items():
                px = _floor_footprint_px(z, cell, model)
                if px is not None:
                    footprints.append({"id": z.id, "kind": z.kind, "camera": cam_id,
                                       "enabled": z.enabled, "points_px": px})
        return {"file": str(self.path), "sha": file_sha(self.path),
                "config_hash": cell.config_hash, "cameras": cams, "polygons": polygons,
                "footprints": footprints, "warnings": list(cell.warnings)}

    def save_polygon(self, zone_id: str, body: dict) -> tuple[zn.Cell, bool, str]:
        """Create or change the image polygon ``zone_id`` from the editor's JSON ``body``
        (camera, kind, points_px, optional name, speed_scale, base). Returns the new cell,
        whether the zone is new, and the config hash before. ConfigError: nothing written."""
        points = _points(body.get("points_px"))
        with self.lock:
            base = body.get("base")
            if base is not None and base != file_sha(self.path):
                raise ConfigError(f"{self.path}: the zone file changed since this page loaded "
                                  "it: reload the page and edit again")
            before = self.cell().config_hash
            data = zn.read_cell_document(self.path)
            zn.parse_cell(data, self.path)  # refuse to edit a file that is already invalid
            zones = data.setdefault("zones", [])
            index = next((k for k, z in enumerate(zones)
                          if isinstance(z, dict) and z.get("id") == zone_id), None)
            new = index is None
            if new:
                zone: dict[str, Any] = {"id": zone_id, "name": str(body.get("name") or ""),
                                        "kind": _kind(body.get("kind")), "shape": "polygon",
                                        "camera": str(body.get("camera") or ""),
                                        "points_px": points}
                if zone["kind"] == "warning":
                    zone["speed_scale"] = _speed(body.get("speed_scale"))
                zones.append(zone)
            else:
                zone = zones[index]
                if zone.get("shape") != "polygon":
                    raise ConfigError(f"{self.path}: zone '{zone_id}' is a {zone.get('shape')} "
                                      "volume: edit it with 'monitor zones edit'")
                zone["points_px"] = points
                if body.get("kind") is not None and body["kind"] != zone.get("kind"):
                    zone["kind"] = _kind(body["kind"])
                    if zone["kind"] != "warning":
                        zone.pop("speed_scale", None)
                if body.get("speed_scale") is not None and zone.get("kind") == "warning":
                    zone["speed_scale"] = _speed(body["speed_scale"])
                if body.get("name") is not None:
                    zone["name"] = str(body["name"])
            cell = zn.write_cell_data(data, self.path)  # validates first: a fault writes nothing
            self._cached = None
            return cell, new, before


def _kind(value: Any) -> str:
    if value not in EDITABLE_KINDS:
        raise ConfigError(f"kind {value!r}: one of {', '.join(EDITABLE_KINDS)}")
    return str(value)


def _speed(value: Any) -> float:
    try:
        s = float(value)
    except (TypeError, ValueError):
        raise ConfigError("a warning zone needs speed_scale (allowed speed fraction, "
                          "0 <= s < 1)") from None
    return s


def _points(value: Any) -> list[list[float]]:
    if not isinstance(value, list) or len(value) > MAX_POINTS:
        raise ConfigError(f"points_px: a list of at most {MAX_POINTS} [x, y] points")
    out = []
    for p in value:
        if (not isinstance(p, list) or len(p) != 2
                or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in p)
                or not all(math.isfinite(v) for v in p)):
            raise ConfigError("points_px: each point is [x, y] in pixels")
        out.append([round(float(p[0]), 1), round(float(p[1]), 1)])
    return out


def _floor_footprint_px(z: Any, cell: zn.Cell, model) -> list[list[float]] | None:
    """A volume's outline at its lowest z, projected into the camera (None: not in view)."""
    if z.shape == "mesh":  # a mesh has no floor outline of its own
        return None
    try:
        lines = volume_outline_m(z, cell)
    except (ConfigError, ValueError, KeyError):
        return None
    if not lines:
        return None
    px, front = model.project(np.asarray(lines[0], float))
    if not np.all(front) or not np.all(np.isfinite(px)):
        return None
    return [[round(float(u), 1), round(float(v), 1)] for u, v in px]
