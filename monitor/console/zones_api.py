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

An edit that weakens protection (``monitor.zones.weaken``: a protective zone removed, shrunk,
made a mask or mutable, a mask added ...) is never written into the zone file: it goes to the
draft beside it (``cell.draft.yaml``, ``draft_path``), which takes effect only when an operator
signs it (``monitor zones apply --zones cell.draft.yaml``: the service promotes the draft with
the signed hash into its zone file and applies it, ``monitor.service.zone_swap``). Why: the file
is what a restart loads, so an unsigned weakening saved there took effect at the next restart
(issue 48: a protective polygon made a mask, a box moved, a restart: SLOW x0.3 with a person
inside). While a draft exists every edit starts from it; an edit that leaves it no weaker than
the zone file is written into the file and the draft goes.
"""

from __future__ import annotations

import hashlib
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from monitor import zones as zn
from monitor.errors import ConfigError
from monitor.zones.draw import volume_outline_m
from monitor.zones.files import draft_path
from monitor.zones.schema import PolygonZone
from monitor.zones.weaken import cell_weakenings

EDITABLE_KINDS = ("protective", "warning", "mask", "watch", "occluder")
MAX_POINTS = 1000


def file_sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@dataclass(frozen=True)
class Saved:
    """A saved edit: the new cell, the zone file's hash before, what it weakens (empty: it
    was written into the zone file) and the file written (the draft when it weakens)."""

    cell: zn.Cell
    before: str
    weakens: tuple[str, ...]
    file: Path

    @property
    def is_draft(self) -> bool:
        return bool(self.weakens)


class ZoneEditor:
    """The zone file the console shows and edits; saves are serialised."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.draft = draft_path(self.path)
        self.lock = threading.Lock()  # every save of the file, by any editor
        self._cached: tuple[str, zn.Cell] | None = None
        self.cell()  # a broken zone file stops the console's start, with its one line

    def source(self) -> Path:
        """The file edits start from: the draft while there is one, else the zone file."""
        return self.draft if self.draft.is_file() else self.path

    def editing_cell(self) -> zn.Cell:
        """The cell edits start from (the draft's, while there is one)."""
        source = self.source()
        return self.cell() if source == self.path else zn.load_cell(source)

    def draft_info(self) -> dict | None:
        """The draft waiting for a signed apply: file, hash and what it weakens (None: no
        draft, or one that does not parse: then it is said as an error)."""
        if not self.draft.is_file():
            return None
        try:
            cell = zn.load_cell(self.draft)
            weakens = cell_weakenings(self.cell(), cell)
        except ConfigError as exc:
            return {"file": str(self.draft), "error": str(exc).splitlines()[0]}
        return {"file": str(self.draft), "config_hash": cell.config_hash, "weakens": weakens,
                "apply": f"monitor zones apply --zones {self.draft} --operator NAME"}

    def edit(self, base: Any, change: Callable[[Any], None]) -> Saved:
        """Apply ``change(document)`` to the file edits start from and save it validated: into
        the zone file when it weakens nothing against it, else into the draft. ``base``: the
        sha256 of the file the page loaded (None: no check). ConfigError: nothing written."""
        with self.lock:
            source = self.source()
            if base is not None and base != file_sha(source):
                raise ConfigError(f"{source}: the zone file changed since this page loaded "
                                  "it: reload the page and edit again")
            live = self.cell()
            data = zn.read_cell_document(source)
            zn.parse_cell(data, source)  # refuse to edit a file that is already invalid
            change(data)
            weakens = tuple(cell_weakenings(live, zn.parse_cell(data, self.path)))
            target = self.draft if weakens else self.path
            cell = zn.write_cell_data(data, target)  # validates first: a fault writes nothing
            if not weakens:
                self.draft.unlink(missing_ok=True)  # nothing weaker waits any more
            self._cached = None
            return Saved(cell, live.config_hash, weakens, target)

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
        cell = self.editing_cell()
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
        return {"file": str(self.path), "sha": file_sha(self.source()),
                "config_hash": cell.config_hash, "cameras": cams, "polygons": polygons,
                "footprints": footprints, "warnings": list(cell.warnings),
                "draft": self.draft_info()}

    def save_polygon(self, zone_id: str, body: dict) -> tuple[Saved, bool]:
        """Create or change the image polygon ``zone_id`` from the editor's JSON ``body``
        (camera, kind, points_px, optional name, speed_scale, base). Returns the save and
        whether the zone is new. ConfigError: nothing written."""
        points = _points(body.get("points_px"))
        added: list[bool] = []

        def change(data: Any) -> None:
            zones = data.setdefault("zones", [])
            index = next((k for k, z in enumerate(zones)
                          if isinstance(z, dict) and z.get("id") == zone_id), None)
            added.append(index is None)
            if index is None:
                zone: dict[str, Any] = {"id": zone_id, "name": str(body.get("name") or ""),
                                        "kind": _kind(body.get("kind")), "shape": "polygon",
                                        "camera": str(body.get("camera") or ""),
                                        "points_px": points}
                if zone["kind"] == "warning":
                    zone["speed_scale"] = _speed(body.get("speed_scale"))
                zones.append(zone)
                return
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

        saved = self.edit(body.get("base"), change)
        return saved, added[0]


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
