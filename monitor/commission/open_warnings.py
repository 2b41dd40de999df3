"""The report's open warnings, on its first page: everything a signer must know is not as it
should be. One function per concern in ``CHECKS`` (each ``Facts -> list of lines``), in the
order the first page lists them; a new concern is one more function there (the references'
own checks sit in ``references``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from monitor.commission.cut_feet import hidden_feet_doubts
from monitor.commission.verdict import DEFAULT_LIMITS, WalkLimits, merge_zone
from monitor.config import MonitorConfig
from monitor.detector.envelope import sidecar_path
from monitor.detector.test_model import live_cameras
from monitor.driver import protective_warning
from monitor.health.references import (
    choose_references,
    missing_reference_warnings,
    reference_warnings,
)
from monitor.zones import Cell


@dataclass(frozen=True)
class Facts:
    """What the warnings are drawn from (the report's inputs, read)."""

    config: MonitorConfig
    cell: Cell | None
    status: dict | None
    walks: list[dict]
    model_path: Path
    test_model: bool  # the model is the synthetic test model
    reaction: dict  # the report's reaction section (S_p figures)
    zones: list[dict]  # the report's zone details (details.zones)
    limits: WalkLimits = DEFAULT_LIMITS


def test_model(f: Facts) -> list[str]:
    live = live_cameras(f.config.cameras)
    if f.test_model and live:
        return [f"the synthetic TEST model watches live camera "
                f"{', '.join(c.id for c in live)}: it detects only the demo's magenta figures, "
                "never a real person"]
    return []


def zone_file(f: Facts) -> list[str]:
    out = [w for w in [protective_warning(f.cell)] if w]
    return out + [f"zone file: {w}" for w in (f.cell.warnings if f.cell else ())]


def references(f: Facts) -> list[str]:
    """Cameras without a reference image (no "moved" or defocus check against the
    commissioned view) and cameras with two references."""
    # a real camera without one: glare and the image conditions are judged by the model
    # envelope's absolute limits, and a view moved or blurred before start is not seen
    out = list(reference_warnings(f.config, f.cell)) + missing_reference_warnings(f.config, f.cell)
    for camera_id, choice in sorted(choose_references(f.config, f.cell).items()):
        if choice.path is not None and not Path(choice.path).is_file():
            out.append(f"camera {camera_id}: its reference image {choice.path} is missing")
    return out


def keys(f: Facts) -> list[str]:
    if f.config.bus.allow_unsigned_resets:
        return ["resets are accepted without an operator key"]
    return []


def separation(f: Facts) -> list[str]:
    """S_p (configured or measured) larger than a protective zone's extent: a person at its
    edge is closer than the robot can stop in."""
    worst = max([f.reaction.get("s_p_configured_m") or 0.0]
                + [m.get("s_p_m") or 0.0 for m in (f.reaction.get("measured") or {}).values()])
    return [f"S_p {worst:.2f} m is larger than the extent of protective zone {z['id']} "
            f"({z['extent_m']:g} m): a person entering at its edge is nearer the robot than it "
            "can stop in (enlarge the zone, or lower T_r or the programmed speed)"
            for z in f.zones if z["kind"] == "protective" and z["enabled"]
            and z.get("extent_m") and worst > z["extent_m"]]


def host(f: Facts) -> list[str]:
    if f.status is None:
        return ["no status of the running service given (--status): capacity and the "
                "measured reaction time are not in this report"]
    out = [f"capacity: {w}" for w in (f.status.get("capacity") or {}).get("warnings", [])]
    if (f.status.get("reaction_budget") or {}).get("exceeded"):
        out.append("the measured reaction time exceeds the configured T_r")
    return out


def walk(f: Facts) -> list[str]:
    if not f.walks:
        return ["no walk test given (--walk): coverage and times to STOP are not shown"]
    out = []
    zones_hash = f.cell.config_hash if f.cell else ""
    for k, w in enumerate(f.walks):
        if w.get("zones_hash") != zones_hash:
            out.append(f"walk {k + 1} ({w.get('video')}) was made with other zones than these")
        out += hidden_feet_doubts(w)
        if not w.get("truth") and any(z.get("entries") for z in w.get("zones", [])):
            out.append(f"walk {k + 1}: time to STOP is 0 by construction without ground truth "
                       "(the entry is the first detection; the frames the detector missed "
                       "before it show as gaps, the host's delays are the reaction budget)")
    walked = {w.get("camera") for w in f.walks}
    for cam in sorted(f.cell.cameras) if f.cell else ():
        if cam not in walked:
            out.append(f"camera {cam}: never walked (no walk recorded from it)")
    for z in f.zones:
        if z["kind"] == "protective" and z["enabled"]:
            out += _protective_walk(z["id"], merge_zone(z["id"], f.walks), f.limits)
        elif z["kind"] == "warning" and z["enabled"]:
            share = (merge_zone(z["id"], f.walks) or {}).get("seen_share")
            if share is not None and share < f.limits.min_walked:
                out.append(f"warning zone {z['id']}: {100 * share:.0f} % of its visible floor "
                           "was walked")
    return out


def _protective_walk(zone_id: str, m: dict | None, limits: WalkLimits) -> list[str]:
    if m is None:
        return []
    out = []
    if m["blind_spots"]:
        out.append(f"zone {zone_id}: {len(m['blind_spots'])} floor cells no camera sees "
                   "(blind spots)")
    share = m["seen_share"]
    if share is not None and share < limits.min_walked:
        out.append(f"zone {zone_id}: {100 * share:.0f} % of its visible floor was walked")
    out += [f"zone {zone_id}: entry at {e['entry_s']} s (walk {e['walk']}) without a STOP"
            for e in m["entries"] if e.get("stop_s") is None]
    for c in m["corners"]:
        x, y = c["corner_m"]
        if not c.get("frames_seen"):
            out.append(f"zone {zone_id}: corner ({x:g}, {y:g}) m: no person seen there in the "
                       "walk (crouch there)")
        elif c.get("frames_near") and c["frames_seen"] < c["frames_near"]:
            out.append(f"zone {zone_id}: corner ({x:g}, {y:g}) m: the person was seen in "
                       f"{c['frames_seen']} of the {c['frames_near']} frames they were there")
    return out


def model(f: Facts) -> list[str]:
    if not sidecar_path(f.model_path).is_file():
        return ["the model has no measured envelope (monitor model envelope)"]
    return []


CHECKS: tuple[Callable[[Facts], list[str]], ...] = (
    test_model, zone_file, references, keys, separation, host, walk, model)


def open_warnings(facts: Facts) -> list[str]:
    return [line for check in CHECKS for line in check(facts)]
