"""The setup page's view and edits of the zone file: zone sets and their switching rules, each
zone's mute setting, and the corners of cell-space boxes (issue 32).

The same rules as the command line: a mute setting changes through ``set_mute`` and the
switching rules through ``set_rules`` (``monitor.zones.settings``, what ``monitor zones mute``
and ``monitor zones set rules`` call), a box through its ``min_m``/``max_m``; then the WHOLE
file is validated by the zone file's loader (``write_cell_data``: a mute over 3600 s, a default
set that does not exist, a box with its corners inverted or not finite ... are refused with the
one-line message ``monitor zones`` prints) and only then written atomically (``FILE.bak``
kept). Saves share the zone editor's lock and its stale-page check (``base``: the sha256 of the
file the page loaded). Like every console edit it is a draft: the running monitor keeps its
zone set until an operator applies the file with ``monitor zones apply`` (signed).

Only boxes in the cell frame (``shape: box`` without ``follow``) are edited here; extrusions,
cylinders and meshes are drawn on the floor plan and edited with ``monitor zones edit``.
"""

from __future__ import annotations

from typing import Any

from monitor import zones as zn
from monitor.console.edit_body import BadRequest
from monitor.console.zones_api import Saved, ZoneEditor, file_sha
from monitor.errors import ConfigError
from monitor.zones.draw import volume_outline_m
from monitor.zones.settings import describe_mute, find_zone, rules_of, set_mute, set_rules

MUTE_FIELDS = ("operators", "max_s", "as", "speed_scale", "unmutable", "remove", "base")
RULES_FIELDS = ("allow", "any", "none", "switch_over_s", "default_set", "selector_ttl_s",
                "no_selector_ttl", "base")
VOLUME_FIELDS = ("min_m", "max_m", "base")
TEXT = ("as", "default_set", "base")
MAX_LIST = 1000


def _flag(body: dict, name: str) -> bool:
    value = body.get(name, False)
    if not isinstance(value, bool):
        raise BadRequest(f"{name}: true or false")
    return value


def _number(body: dict, name: str) -> float | None:
    value = body.get(name)
    if value is not None and (isinstance(value, bool) or not isinstance(value, int | float)):
        raise BadRequest(f"{name}: a number")
    return None if value is None else float(value)


def _names(value: Any, name: str) -> list[str]:
    if not isinstance(value, list) or len(value) > MAX_LIST or \
            not all(isinstance(v, str) and len(v) <= 64 for v in value):
        raise BadRequest(f"{name}: a list of names (at most {MAX_LIST}, 64 characters each)")
    return value


def _corner(value: Any, name: str) -> list[float]:
    if not isinstance(value, list) or len(value) != 3 or \
            not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
        raise BadRequest(f"{name}: [x, y, z] in metres")
    return [float(v) for v in value]


class SetupEditor:
    """Reads and edits the zone file of a ``ZoneEditor`` (one lock for every save)."""

    def __init__(self, editor: ZoneEditor) -> None:
        self.editor = editor

    def data(self) -> dict:
        """Zone sets and rules, mute settings, and the floor outlines of the volumes (metres,
        cell frame, for the plan; boxes with their corners, editable)."""
        cell = self.editor.editing_cell()  # the draft while there is one
        spec = cell.spec
        sets = [{"id": s.id, "name": s.name, "zones": list(s.zones),
                 "speed_scale": s.speed_scale, "default": s.id == spec.default_set}
                for s in spec.sets]
        raw = zn.read_cell_data(self.editor.source())
        by_id = {z.get("id"): z for z in raw.get("zones") or [] if isinstance(z, dict)}
        mutes, volumes = [], []
        for z in cell.zones:
            if z.kind in ("protective", "warning"):
                mute = z.mute.model_dump(by_alias=True) if z.mute else None
                mutes.append({"id": z.id, "kind": z.kind, "mute": mute,
                              "unmutable": bool(z.unmutable),
                              "describe": describe_mute(by_id.get(z.id, {}))})
            if not z.is_volume:
                continue
            follows = getattr(z, "follow", None) is not None  # tool frame: not on the plan
            entry: dict[str, Any] = {"id": z.id, "name": z.name, "kind": z.kind,
                                     "shape": z.shape, "enabled": z.enabled,
                                     "follows_tool": follows,
                                     "outline_m": [] if follows else _floor_outline(z, cell)}
            if z.shape == "box" and z.follow is None:
                entry.update(min_m=list(z.min_m), max_m=list(z.max_m), yaw_deg=z.yaw_deg,
                             editable=True)
            volumes.append(entry)
        return {"file": str(self.editor.path), "sha": file_sha(self.editor.source()),
                "draft": self.editor.draft_info(),
                "config_hash": cell.config_hash, "sets": sets, "rules": rules_of(spec),
                "mutes": mutes, "volumes": volumes}

    def _edit(self, base: Any, change) -> Saved:
        """Apply ``change(data)`` to the document edits start from and save it validated
        (into the draft when it weakens protection: ``ZoneEditor.edit``). ConfigError: nothing
        written."""
        return self.editor.edit(base, change)

    def save_mute(self, zone_id: str, body: dict) -> Saved:
        """``body``: operators (names), max_s, as, speed_scale, or unmutable / remove."""
        operators = _names(body["operators"], "operators") if body.get("operators") is not None \
            else None
        max_s, speed = _number(body, "max_s"), _number(body, "speed_scale")
        unmutable, remove = _flag(body, "unmutable"), _flag(body, "remove")
        as_ = body.get("as")

        def change(data: dict) -> None:
            zone = find_zone(data, zone_id, str(self.editor.path))
            if not set_mute(zone, operators, max_s, as_, speed, unmutable, remove,
                            what=f"mute of {zone_id}"):
                raise ConfigError(f"mute of {zone_id}: nothing to change (give operators and "
                                  "max_s, unmutable or remove)")
        return self._edit(body.get("base"), change)

    def save_rules(self, body: dict) -> Saved:
        """``body``: allow ([[from, to], ...]), any, none, switch_over_s, default_set,
        selector_ttl_s, no_selector_ttl; fields not given stay as they are."""
        allow = body.get("allow")
        if allow is not None:
            if not isinstance(allow, list) or len(allow) > MAX_LIST:
                raise BadRequest(f"allow: a list of [from, to] set ids (at most {MAX_LIST})")
            allow = [_names(m, "allow") for m in allow]
            if any(len(m) != 2 for m in allow):
                raise BadRequest("allow: each switch is [from, to]")
        args = (allow, _flag(body, "any"), _flag(body, "none"), _number(body, "switch_over_s"),
                body.get("default_set"), _number(body, "selector_ttl_s"),
                _flag(body, "no_selector_ttl"))
        return self._edit(body.get("base"),
                          lambda data: set_rules(data, *args, what="zone set rules"))

    def save_box(self, zone_id: str, body: dict) -> Saved:
        """``body``: min_m and max_m, [x, y, z] metres in the cell frame."""
        lo, hi = _corner(body.get("min_m"), "min_m"), _corner(body.get("max_m"), "max_m")

        def change(data: dict) -> None:
            zone = find_zone(data, zone_id, str(self.editor.path))
            if zone.get("shape") != "box" or zone.get("follow") is not None:
                raise ConfigError(f"{self.editor.path}: zone '{zone_id}' is no box in the cell "
                                  "frame: edit it with 'monitor zones edit'")
            zone["min_m"], zone["max_m"] = lo, hi
        return self._edit(body.get("base"), change)


def _floor_outline(z: Any, cell: zn.Cell) -> list[list[float]]:
    """The volume's lowest ring, x/y metres (a mesh: none drawn)."""
    if z.shape == "mesh":
        return []
    try:
        ring = volume_outline_m(z, cell)[0]
    except (ConfigError, ValueError, KeyError, IndexError):
        return []
    return [[round(float(x), 3), round(float(y), 3)] for x, y, _ in ring[:-1]]
