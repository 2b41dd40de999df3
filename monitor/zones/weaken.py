"""Whether a changed zone file protects less than the one before: the console's rule for which
edits need an operator's signed apply (docs/console.md, "Edits that weaken protection").

A change weakens protection when, against the file before, a protective zone is removed or
disabled, made another kind (a mask, a warning zone ...), shrunk or moved so that some of the
space or image area it covered is no longer covered, or made mutable (a ``mute:`` added, a longer
``max_s``, more operators, ``as: none``, a faster muted speed); when a mask is added or grows
(a mask hides the persons anchored in it); when a warning zone allows more speed or goes; or
when the zone set rules change (which zones apply then is not proved stronger here). What is not
proved stronger counts as weaker: the rule errs towards asking for a signature.

Pure: geometry by rasterising both outlines on one grid (image polygons in pixels, floor
outlines in millimetres), no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import cv2
import numpy as np

GRID_PX = 2048  # the raster's longer side
TOLERANCE_CELLS = 2  # uncovered raster cells allowed (rounding at the outline)


def _uncovered(old: Sequence[Sequence[float]], new: Sequence[Sequence[float]]) -> bool:
    """Whether some of polygon ``old`` lies outside polygon ``new`` (same units)."""
    a, b = np.asarray(old, float), np.asarray(new, float)
    if len(a) < 3:
        return False
    if len(b) < 3:
        return True
    lo = np.minimum(a.min(axis=0), b.min(axis=0))
    span = float(max(np.max(np.maximum(a.max(axis=0), b.max(axis=0)) - lo), 1e-9))
    scale = (GRID_PX - 4) / span
    size = (GRID_PX, GRID_PX)

    def raster(points: np.ndarray) -> np.ndarray:
        img = np.zeros(size, np.uint8)
        pts = np.round((points - lo) * scale + 2).astype(np.int32)
        cv2.fillPoly(img, [pts], 1)
        return img

    old_r, new_r = raster(a), cv2.dilate(raster(b), np.ones((3, 3), np.uint8))
    return int(np.count_nonzero(old_r & (1 - new_r))) > TOLERANCE_CELLS


def _box_outline(z: Any) -> list[tuple[float, float]]:
    (x0, y0, _), (x1, y1, _) = z.min_m, z.max_m
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    yaw = math.radians(getattr(z, "yaw_deg", 0.0) or 0.0)
    if not yaw:
        return corners
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    c, s = math.cos(yaw), math.sin(yaw)
    return [(cx + (x - cx) * c - (y - cy) * s, cy + (x - cx) * s + (y - cy) * c)
            for x, y in corners]


def _outline(z: Any) -> tuple[str, list, tuple[float, float] | None] | None:
    """(frame, floor or image outline, z range) of a zone; None: not comparable (a mesh, a
    zone that follows the tool)."""
    shape = getattr(z, "shape", "")
    if getattr(z, "follow", None) is not None:
        return None
    if shape == "polygon":
        return f"image:{z.camera}", [tuple(p) for p in z.points_px], None
    if shape == "box":
        return "floor", _box_outline(z), (z.min_m[2], z.max_m[2])
    if shape == "extrude":
        return "floor", [tuple(p) for p in z.points_m], (z.z_min_m, z.z_max_m)
    if shape == "cylinder":
        n = 64
        cx, cy = z.center_m
        r = z.radius_m
        return "floor", [(cx + r * math.cos(2 * math.pi * k / n),
                          cy + r * math.sin(2 * math.pi * k / n)) for k in range(n)], \
            (z.z_min_m, z.z_max_m)
    return None


def _shrinks(old: Any, new: Any) -> bool:
    """Whether ``new`` fails to cover all of ``old`` (unknown geometry: it may)."""
    if old.shape == "mesh" and new.shape == "mesh":
        return (old.file, getattr(old, "scale", 1.0)) != (new.file, getattr(new, "scale", 1.0))
    a, b = _outline(old), _outline(new)
    if a is None or b is None:
        return (a is None) != (b is None) or old != new
    if a[0] != b[0]:
        return True  # another camera or image/floor: not the same area
    if a[2] is not None and b[2] is not None and (b[2][0] > a[2][0] + 1e-6
                                                  or b[2][1] < a[2][1] - 1e-6):
        return True  # lower or less high
    return _uncovered(a[1], b[1])


def _more_mutable(old: Any, new: Any) -> bool:
    m_old, m_new = getattr(old, "mute", None), getattr(new, "mute", None)
    if m_new is None:
        return False
    if m_old is None:
        return True
    return (m_new.max_s > m_old.max_s or not set(m_new.operators) <= set(m_old.operators)
            or (m_new.as_ == "none" and m_old.as_ != "none")
            or (m_new.speed_scale or 0.0) > (m_old.speed_scale or 0.0)
            or (m_old.speed_scale is not None and m_new.speed_scale is None))


def weakenings(old_zones: Iterable[Any], new_zones: Iterable[Any], old_rules: Any = None,
               new_rules: Any = None) -> list[str]:
    """What ``new_zones`` (zone specs) protect less than ``old_zones``, one line each (empty:
    nothing weaker). ``*_rules``: the zone set rules of each file (compared for equality)."""
    old = {z.id: z for z in old_zones}
    new = {z.id: z for z in new_zones}
    out: list[str] = []
    for zid, was in old.items():
        now = new.get(zid)
        if was.kind == "protective" and was.enabled:
            if now is None or not now.enabled:
                out.append(f"protective zone {zid} {'removed' if now is None else 'disabled'}")
                continue
            if now.kind != "protective":
                out.append(f"protective zone {zid} made a {now.kind} zone")
                continue
            if _shrinks(was, now):
                out.append(f"protective zone {zid} shrunk or moved (some of what it covered is "
                           "no longer covered)")
            if _more_mutable(was, now):
                out.append(f"protective zone {zid} made mutable (or more mutable)")
        elif was.kind == "warning" and was.enabled:
            if now is None or not now.enabled or now.kind not in ("warning", "protective"):
                out.append(f"warning zone {zid} removed, disabled or made a "
                           f"{now.kind if now else 'nothing'}")
                continue
            if now.kind == "warning" and (now.speed_scale or 0.0) > (was.speed_scale or 0.0):
                out.append(f"warning zone {zid} allows more speed ({was.speed_scale} -> "
                           f"{now.speed_scale})")
            if now.kind == "warning" and _shrinks(was, now):
                out.append(f"warning zone {zid} shrunk or moved")
            if _more_mutable(was, now):
                out.append(f"warning zone {zid} made mutable (or more mutable)")
        elif was.kind == "mask" and was.enabled and now is not None and now.enabled \
                and now.kind == "mask" and _shrinks(now, was):
            out.append(f"mask {zid} grown or moved (a mask hides the persons in it)")
    for zid, now in new.items():
        was = old.get(zid)
        # (an enabled protective or warning zone made a mask is said above)
        if now.kind == "mask" and now.enabled and (
                was is None or not was.enabled
                or was.kind not in ("mask", "protective", "warning")):
            out.append(f"mask {zid} added (a mask hides the persons in it)")
    if old_rules != new_rules:
        out.append("the zone set rules changed (which zones apply is not proved stronger)")
    return out


def cell_weakenings(old_cell: Any, new_cell: Any) -> list[str]:
    """``weakenings`` of two ``monitor.zones.Cell``s (their zones and zone set rules)."""
    def rules(cell: Any) -> tuple:
        spec = cell.spec
        return (spec.sets, spec.default_set, spec.transitions, spec.switch_over_s,
                spec.selector_ttl_s)

    return weakenings(old_cell.zones, new_cell.zones, rules(old_cell), rules(new_cell))
