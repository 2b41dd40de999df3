"""Edits of a zone's mute setting and of the zone sets' switching rules, on the zone file's
data (the round-trip document of ``read_cell_document``), shared by ``monitor zones mute``,
``monitor zones set rules`` and the console, so both refuse the same things with the same
words. These functions only change the data and refuse contradicting options; the bounds
(``max_s`` at most 3600 s, a speed scale below 1, a set rule naming a set that exists ...) are
the zone file's own validation (``parse_cell``, ``write_cell_data``), which every caller runs on
the whole file before anything is written."""

from __future__ import annotations

from typing import Any

from monitor.errors import ConfigError

MUTE_AS = ("warning", "none")


def find_zone(data: dict, zone_id: str, where: str) -> dict:
    """The zone ``zone_id`` of the file's data; ConfigError when there is none."""
    zone = next((z for z in data.get("zones") or []
                 if isinstance(z, dict) and z.get("id") == zone_id), None)
    if zone is None:
        raise ConfigError(f"{where}: no zone '{zone_id}'")
    return zone


def set_mute(zone: dict, operators: list[str] | None = None, max_s: float | None = None,
             as_: str | None = None, speed_scale: float | None = None,
             unmutable: bool = False, remove: bool = False, what: str = "zones mute") -> bool:
    """Change ``zone``'s mute section: allow (``operators``, ``max_s``, ``as_``,
    ``speed_scale``; unset ones stay as they are), ``unmutable`` or ``remove``. Returns False
    when nothing was asked (show only). ConfigError on contradicting options or a first mute
    rule without operators and max_s."""
    allow = [v is not None for v in (operators, max_s, as_, speed_scale)]
    if sum((any(allow), unmutable, remove)) > 1:
        raise ConfigError(f"{what}: give either --operators/--max-s (allow), --unmutable or "
                          "--remove")
    if not any(allow) and not unmutable and not remove:
        return False
    if as_ is not None and as_ not in MUTE_AS:
        raise ConfigError(f"{what}: as {as_!r}: one of {', '.join(MUTE_AS)}")
    if unmutable:
        zone.pop("mute", None)
        zone["unmutable"] = True
    elif remove:
        zone.pop("mute", None)
        zone.pop("unmutable", None)
    else:
        mute = dict(zone.get("mute") or {})
        if operators is not None:
            mute["operators"] = [o.strip() for o in operators if o.strip()]
        if max_s is not None:
            mute["max_s"] = max_s
        if as_ is not None:
            mute["as"] = as_
        if speed_scale is not None:
            mute["speed_scale"] = speed_scale
        missing = [f"--{k.replace('_', '-')}" for k in ("operators", "max_s") if k not in mute]
        if missing:
            raise ConfigError(f"{what}: {zone.get('id')} has no mute rule yet: give "
                              f"{' and '.join(missing)}")
        zone.pop("unmutable", None)
        zone["mute"] = mute
    return True


def describe_mute(zone: dict) -> str:
    """The zone's mute rule in one line, as written in the file."""
    mute = zone.get("mute")
    if mute:
        what = "checked as nothing" if mute.get("as") == "none" else \
            f"checked as a warning zone (speed {mute['speed_scale']:g})" \
            if mute.get("speed_scale") is not None else "checked as a warning zone"
        return (f"may be muted by {', '.join(mute.get('operators') or [])} for at most "
                f"{mute.get('max_s'):g} s, {what}")
    if zone.get("unmutable"):
        return "never muted (unmutable)"
    return "no mute rule: " + ("never muted" if zone.get("kind") == "protective"
                               else "cannot be muted")


def parse_moves(texts: list[str], what: str = "zones set rules") -> list[list[str]]:
    """``FROM:TO`` texts as ``[from, to]`` pairs."""
    moves = []
    for text in texts:
        a, sep, b = text.partition(":")
        if not sep or not a.strip() or not b.strip():
            raise ConfigError(f"{what}: --allow {text!r}: expected FROM:TO (two set ids)")
        moves.append([a.strip(), b.strip()])
    return moves


def set_rules(data: dict, allow: list[list[str]] | None = None, any_: bool = False,
              none: bool = False, switch_over_s: float | None = None,
              default_set: str | None = None, selector_ttl_s: float | None = None,
              no_selector_ttl: bool = False, what: str = "zones set rules") -> None:
    """Change the file's switching rules; options not given stay as they are. ``allow``: the
    allowed switches (replaces the list); ``any_``: every switch; ``none``: no switch."""
    if sum((bool(allow), any_, none)) > 1:
        raise ConfigError(f"{what}: give one of --allow, --any or --none")
    if selector_ttl_s is not None and no_selector_ttl:
        raise ConfigError(f"{what}: give --selector-ttl or --no-selector-ttl, not both")
    if allow:
        data["transitions"] = [list(m) for m in allow]
    elif any_:
        data.pop("transitions", None)
    elif none:
        data["transitions"] = []
    if switch_over_s is not None:
        data["switch_over_s"] = switch_over_s
    if default_set is not None:
        data["default_set"] = default_set
    if selector_ttl_s is not None:
        data["selector_ttl_s"] = selector_ttl_s
    elif no_selector_ttl:
        data.pop("selector_ttl_s", None)


def rules_of(data: Any) -> dict:
    """The switching rules as the page shows them (the spec's values)."""
    return {"default_set": data.default_set,
            "transitions": None if data.transitions is None
            else [list(m) for m in data.transitions],
            "switch_over_s": data.switch_over_s, "selector_ttl_s": data.selector_ttl_s}
