"""The walk test's verdict: per zone and per camera PASS or FAIL, with every reason, from one or
more walk results (``walk.json``: one walk per camera, or several passes). Pure (JSON in,
verdicts out), so the report and ``commission walk`` say the same.

A walk proves a zone only when it showed a person being seen there. A zone FAILs while:

* nobody was detected in any walk (``nobody_detected``): the walk saw nothing, whatever else;
* it is protective and was never entered (``never_entered``), or an entry had no STOP
  (``entries_without_stop``);
* it is protective and less than ``MIN_WALKED`` of its visible floor was walked
  (``little_walked``; for a warning zone, which only slows the robot, that is an open warning);
* a camera was frozen, lost, blinded, moved or defocused during a walk (``camera_faults``):
  those frames show nothing about the zone;
* its camera was never walked (``camera_not_walked``: an image zone whose camera no walk comes
  from; a volume zone when no walk at all was given);
* it is protective and the detector lost the walker in it for so many frames in a row that
  the monitor would have let go of them unseen (``detector_gaps``): a lost person's area
  gives up floor the camera has shown empty for ``clear_time``, so a run of missed frames
  spanning ``clear_time`` (from the first missed frame to the last) ends the hold while the
  person is still there, and a reset is accepted with them inside. The walk measures the
  detector's longest miss on this camera, the user raises ``clear_time`` above it. A gap
  from which the walker could have reached floor no camera sees (a blind spot within a walk
  of where they were last seen) is left out: hidden floor is never seen free, the hold stays.

Each reason is its own function of ``(zone, merged, walks, limits)`` in ``ZONE_CHECKS`` (a later
check, e.g. feet hidden in a protective zone, is one more function there). A camera FAILs when
no walk comes from it, nobody was detected in its walks, or it had a camera fault.

Several walks merge per zone: entries and gaps of each walk (named by walk), the floor seen in
any of them (the visible cells that are unvisited in every walk are the unvisited ones), corner
frames summed. Walks made with another zone set than the report's are not merged (the report
warns about them).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from monitor.policy import PolicyConfig

MIN_WALKED = 0.10  # share of a zone's visible floor the walk must have seen a person on
PASS, FAIL = "PASS", "FAIL"
# a walker in a gap reaches at most this far from where they were last seen (a brisk walk, as
# the lost persons' areas grow: monitor.tracking.whereabouts)
GAP_WALK_MPS = 1.5


@dataclass(frozen=True)
class WalkLimits:
    """What a walk must show (the report's options). ``clear_time_s``: the ``[policy]
    clear_time`` the monitor runs with (None: the default policy's)."""

    min_walked: float = MIN_WALKED
    clear_time_s: float | None = None

    @property
    def clear_time(self) -> float:
        return PolicyConfig().clear_time if self.clear_time_s is None else self.clear_time_s


DEFAULT_LIMITS = WalkLimits()


@dataclass(frozen=True)
class Verdict:
    subject: str  # zone or camera id
    what: str  # "protective zone", "warning zone", "camera"
    verdict: str  # PASS or FAIL
    reasons: tuple[str, ...] = ()
    figures: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"subject": self.subject, "what": self.what, "verdict": self.verdict,
                "reasons": list(self.reasons), "figures": self.figures}


def merge_zone(zone_id: str, walks: Sequence[dict]) -> dict | None:
    """One zone's figures over several walks (None: in no walk)."""
    parts = [(k, z) for k, w in enumerate(walks) for z in w.get("zones", [])
             if z.get("zone_id") == zone_id]
    if not parts:
        return None
    first = parts[0][1]
    visible = max(int(z.get("visible_cells") or 0) for _, z in parts)
    unvisited = None
    for _, z in parts:
        cells = {tuple(p) for p in z.get("unvisited") or []}
        unvisited = cells if unvisited is None else unvisited & cells
    seen = max(visible - len(unvisited or ()), max(int(z.get("seen_cells") or 0)
                                                    for _, z in parts))
    corners: dict[tuple, dict] = {}
    for _, z in parts:
        for c in z.get("corners") or []:
            key = tuple(c["corner_m"])
            into = corners.setdefault(key, {"corner_m": list(key), "blind_cells":
                                            c.get("blind_cells", 0), "frames_near": None,
                                            "frames_seen": 0})
            into["frames_seen"] += int(c.get("frames_seen") or 0)
            if c.get("frames_near") is not None:
                into["frames_near"] = (into["frames_near"] or 0) + int(c["frames_near"])
    return {"zone_id": zone_id, "kind": first.get("kind"), "cells": first.get("cells", 0),
            "visible_cells": visible, "seen_cells": seen,
            "seen_share": seen / visible if visible else None,
            "blind_spots": first.get("blind_spots") or [],
            "entries": [{**e, "walk": k + 1} for k, z in parts for e in z.get("entries", [])],
            "gaps": [{**g, "walk": k + 1} for k, z in parts for g in z.get("gaps", [])],
            "corners": list(corners.values()), "walks": [k + 1 for k, _ in parts]}


def detected_frames(walk: dict) -> int:
    """Frames of a walk with a person detected (a walk.json written before the count was kept:
    its detected foot points)."""
    count = walk.get("detected_frames")
    return int(count) if count is not None else len(walk.get("seen_m") or [])


# --- the reasons a zone FAILs: each (zone, merged, walks, limits) -> reasons -------------------

def nobody_detected(zone: dict, merged: dict | None, walks: Sequence[dict],
                    limits: WalkLimits) -> list[str]:
    if walks and not any(detected_frames(w) for w in walks):
        frames = sum(int(w.get("frames") or 0) for w in walks)
        return [f"nobody was detected in the walk ({frames} frames)"]
    return []


def never_entered(zone: dict, merged: dict | None, walks: Sequence[dict],
                    limits: WalkLimits) -> list[str]:
    if zone.get("kind") == "protective" and walks and not (merged or {}).get("entries"):
        return ["the protective zone was never entered"]
    return []


def entries_without_stop(zone: dict, merged: dict | None, walks: Sequence[dict],
                    limits: WalkLimits) -> list[str]:
    if zone.get("kind") != "protective" or merged is None:
        return []
    return [f"entry at {e['entry_s']} s (walk {e['walk']}) without a STOP"
            for e in merged["entries"] if e.get("stop_s") is None]


def little_walked(zone: dict, merged: dict | None, walks: Sequence[dict],
                    limits: WalkLimits) -> list[str]:
    min_walked = limits.min_walked
    share = (merged or {}).get("seen_share")
    if zone.get("kind") != "protective":  # a warning zone only slows: an open warning
        return []
    if share is not None and share < min_walked:
        return [f"{100 * share:.0f} % of the zone's visible floor was walked "
                f"({merged['seen_cells']} of {merged['visible_cells']} cells; at least "
                f"{100 * min_walked:.0f} % asked)"]
    return []


def camera_faults(zone: dict, merged: dict | None, walks: Sequence[dict],
                    limits: WalkLimits) -> list[str]:
    out = []
    for k, w in enumerate(walks):
        for cam, faults in sorted((w.get("camera_faults") or {}).items()):
            if zone.get("camera") not in (None, cam):
                continue  # an image zone of another camera
            what = ", ".join(f"{f.removeprefix('camera_')} in {n} frames"
                             for f, n in sorted(faults.items()))
            out.append(f"camera {cam} was {what} (walk {k + 1})")
    return out


def camera_not_walked(zone: dict, merged: dict | None, walks: Sequence[dict],
                    limits: WalkLimits) -> list[str]:
    if not walks:
        return ["no walk test was given"]
    cam = zone.get("camera")
    if cam is not None and cam not in {w.get("camera") for w in walks}:
        return [f"its camera {cam} was never walked"]
    return []


def feet_hidden(zone: dict, merged: dict | None, walks: Sequence[dict],
                limits: WalkLimits) -> list[str]:
    """A protective zone where the walker's box was cut off by something the zone file does not
    declare (``cut_feet``, docs/occlusion.md): the floor behind it is not what the file says."""
    if zone.get("kind") != "protective":
        return []
    out = []
    for k, w in enumerate(walks):
        for z in w.get("zones", []):
            cells = z.get("feet_hidden") or []
            if z.get("zone_id") == zone.get("id") and cells:
                out.append(f"{len(cells)} floor cells where the walker's feet were hidden by "
                           f"a fixture the zone file does not declare (walk {k + 1}): "
                           "declare an occluder there")
    return out


def detector_gaps(zone: dict, merged: dict | None, walks: Sequence[dict],
                  limits: WalkLimits) -> list[str]:
    """A protective zone where the detector missed the walker in open view for a run of
    frames spanning ``clear_time`` (see the module's rules): the monitor would have let go
    of a person it could not see."""
    if zone.get("kind") != "protective" or merged is None:
        return []
    clear = limits.clear_time
    blind = [tuple(p) for p in merged.get("blind_spots") or []]
    out = []
    for g in merged["gaps"]:
        walk = walks[g["walk"] - 1] if 0 < g.get("walk", 0) <= len(walks) else {}
        interval = float(walk.get("frame_interval_s") or 0.0)
        missed = int(g.get("frames_missed") or 0)
        if interval <= 0.0 or missed < 1:
            continue
        span = (missed - 1) * interval  # seen free from the first missed frame to the last
        if span < clear - 1e-6:
            continue
        last = g.get("last_seen_m")
        reach = GAP_WALK_MPS * float(g.get("duration_s") or 0.0)
        if last is not None and any(math.dist(last, p) <= reach for p in blind):
            continue  # may have been hidden there: that floor is never seen free
        out.append(f"the detector missed the walker for {missed} frames in a row "
                   f"({missed * interval:.2f} s from {g['from_s']:g} s, walk {g['walk']}): "
                   f"with clear_time {clear:g} s the monitor lets go of a person it has not "
                   f"seen for {span:.2f} s, and a reset would be accepted with them inside; "
                   f"raise [policy] clear_time above {missed * interval:.2f} s, or give the "
                   "camera a better view of the zone")
    return out


ZoneCheck = Callable[[dict, "dict | None", Sequence[dict], WalkLimits], list[str]]
ZONE_CHECKS: tuple[ZoneCheck, ...] = (nobody_detected, camera_not_walked, never_entered,
                                      entries_without_stop, little_walked, camera_faults,
                                      feet_hidden, detector_gaps)


def zone_verdicts(zones: Sequence[dict], walks: Sequence[dict],
                  limits: WalkLimits = DEFAULT_LIMITS,
                  checks: Sequence[ZoneCheck] = ZONE_CHECKS) -> list[Verdict]:
    """A verdict for each enabled protective and warning zone (``zones``: the report's zone
    list: id, kind, enabled, camera for an image zone)."""
    out = []
    for zone in zones:
        if not zone.get("enabled", True) or zone.get("kind") not in ("protective", "warning"):
            continue
        merged = merge_zone(zone["id"], walks)
        reasons = [r for check in checks for r in check(zone, merged, walks, limits)]
        figures = {} if merged is None else {
            "entries": len(merged["entries"]), "seen_cells": merged["seen_cells"],
            "visible_cells": merged["visible_cells"], "seen_share": merged["seen_share"],
            "walks": merged["walks"]}
        out.append(Verdict(zone["id"], f"{zone['kind']} zone", FAIL if reasons else PASS,
                           tuple(reasons), figures))
    return out


def camera_verdicts(cameras: Sequence[str], walks: Sequence[dict]) -> list[Verdict]:
    """A verdict for each camera of the cell."""
    out = []
    for cam in cameras:
        own = [w for w in walks if w.get("camera") == cam]
        reasons = []
        if not own:
            reasons.append("never walked: no walk was recorded from this camera")
        elif not any(detected_frames(w) for w in own):
            reasons.append("nobody was detected in its walk")
        for w in walks:
            faults = (w.get("camera_faults") or {}).get(cam) or {}
            if faults:
                reasons.append("was " + ", ".join(f"{f.removeprefix('camera_')} in {n} frames"
                                                  for f, n in sorted(faults.items()))
                               + f" during the walk of {w.get('camera')}")
        figures = {"walks": len(own), "frames": sum(int(w.get("frames") or 0) for w in own),
                   "detected_frames": sum(detected_frames(w) for w in own)}
        out.append(Verdict(cam, "camera", FAIL if reasons else PASS, tuple(reasons), figures))
    return out
