"""The lost persons' areas and the hidden pockets in the console's live view: read from the
monitor's detections message (``monitor.pipeline.pocket_views.screen_body``), drawn over the
live picture in the look of the annotated replay (``monitor.records.areas_draw``: a yellow
fill where a lost person could be, purple hatching where the camera cannot see, a pocket
outlined with its count), and listed on the live page (why the cell is held, whether waiting
can end it, and what a pocket's count needs to end it).

The message comes off the bus: every field is checked and a bad one is left out, never drawn
as something else; at most ``MAX_AREAS`` areas and ``MAX_POINTS`` points per outline.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from monitor.pipeline.pocket_views import pocket_text
from monitor.records.areas_draw import AREA_ALPHA, AREA_BGR, UNSEEN_BGR, pocket_colour

MAX_AREAS = 64
MAX_OUTLINES = 64
MAX_POINTS = 4096
HATCH_PX = 8  # the unseen hatching's line spacing in live-picture pixels


def _outlines(value) -> list[np.ndarray]:
    """Polygons (K, 2) from a list of [[x, y], ...] (camera-frame pixels); bad ones left out."""
    out = []
    for poly in value[:MAX_OUTLINES] if isinstance(value, list) else ():
        if not isinstance(poly, list) or not 3 <= len(poly) <= MAX_POINTS:
            continue
        try:
            pts = np.array([[float(p[0]), float(p[1])] for p in poly], np.float64)
        except (TypeError, ValueError, IndexError):
            continue
        if np.all(np.isfinite(pts)) and np.all(np.abs(pts) < 1e5):
            out.append(pts)
    return out


def _text(value, limit: int = 64) -> str:
    return str(value)[:limit] if isinstance(value, (str, int)) else "?"


def area_list(det: dict | None) -> list[dict]:
    """The areas of one camera's detections message as the live page lists them (checked):
    ``{"person", "zones", "regions", "waiting_ends", "lost_since"}``."""
    out = []
    areas = (det or {}).get("areas")
    for a in areas[:MAX_AREAS] if isinstance(areas, list) else ():
        if not isinstance(a, dict):
            continue
        lost = a.get("lost_since")
        out.append({
            "person": _text(a.get("person")),
            "zones": [_text(z) for z in a.get("zones", [])[:16]]
            if isinstance(a.get("zones"), list) else [],
            "regions": [_text(r) for r in a.get("regions", [])[:16]]
            if isinstance(a.get("regions"), list) else [],
            # unknown: it is not said that waiting (or a person seen leaving) ends it
            "waiting_ends": a.get("waiting_ends") is True,
            "leaving_ends": a.get("leaving_ends") is True,
            "lost_since": float(lost) if isinstance(lost, (int, float))
            and math.isfinite(lost) else None})
    return out


def _count(value) -> int | None:
    """A pocket's count: a whole number >= 0, else None (unknown: drawn and listed as held)."""
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 \
        else None


def pocket_list(det: dict | None) -> list[dict]:
    """The pockets of one camera's detections message as the live page lists them (checked):
    ``{"pocket", "count", "label", "why", "regions"}``; a count that is not a whole number
    >= 0 is unknown (held), and the label is made here from the checked fields, never taken
    from the message."""
    out = []
    pockets = (det or {}).get("pockets")
    for p in pockets[:MAX_AREAS] if isinstance(pockets, list) else ():
        if not isinstance(p, dict):
            continue
        count = _count(p.get("count"))
        name = _text(p.get("pocket"))
        out.append({"pocket": name, "count": count, "label": pocket_text(name, count),
                    "why": _text(p.get("why"), 120),
                    "regions": [_text(r) for r in p.get("regions", [])[:16]]
                    if isinstance(p.get("regions"), list) else []})
    return out


def _fill(img: np.ndarray, polys: list[np.ndarray], sx: float, sy: float) -> np.ndarray:
    mask = np.zeros(img.shape[:2], np.uint8)
    scaled = [np.round(p * (sx, sy)).astype(np.int32) for p in polys]
    if scaled:
        cv2.fillPoly(mask, scaled, 1)
    return mask.astype(bool)


def draw_live_areas(img: np.ndarray, det: dict, sx: float, sy: float) -> int:
    """Hatch what the camera cannot see and fill each lost person's area (in place; ``sx``,
    ``sy``: live-picture pixels per camera-frame pixel); how many areas were drawn."""
    unseen = _fill(img, _outlines(det.get("unseen_px")), sx, sy)
    if unseen.any():
        h, w = img.shape[:2]
        yy, xx = np.mgrid[0:h, 0:w]
        lines = ((xx + yy) % HATCH_PX == 0) | ((xx - yy) % HATCH_PX == 0)
        img[unseen & lines] = UNSEEN_BGR
    areas = det.get("areas")
    drawn = 0
    colour = np.array(AREA_BGR, np.float32)
    for a in areas[:MAX_AREAS] if isinstance(areas, list) else ():
        polys = _outlines(a.get("outlines_px")) if isinstance(a, dict) else []
        if not polys:
            continue
        inside = _fill(img, polys, sx, sy)
        img[inside] = (img[inside].astype(np.float32) * (1.0 - AREA_ALPHA)
                       + colour * AREA_ALPHA).astype(np.uint8)
        cv2.polylines(img, [np.round(p * (sx, sy)).astype(np.int32) for p in polys], True,
                      AREA_BGR, 2, cv2.LINE_AA)
        drawn += 1
    return drawn


def draw_live_pockets(img: np.ndarray, det: dict, sx: float, sy: float) -> int:
    """Outline each hidden pocket in its colour and label it with its count below it (in
    place, as the annotated replay does); how many pockets were drawn."""
    pockets = det.get("pockets")
    drawn = 0
    for p in pockets[:MAX_AREAS] if isinstance(pockets, list) else ():
        polys = _outlines(p.get("outlines_px")) if isinstance(p, dict) else []
        if not polys:
            continue
        count = _count(p.get("count"))
        colour = pocket_colour(count)
        scaled = [np.round(q * (sx, sy)).astype(np.int32) for q in polys]
        cv2.polylines(img, scaled, True, colour, 2, cv2.LINE_AA)
        x, y, _, h = cv2.boundingRect(np.concatenate(scaled))
        text = pocket_text(_text(p.get("pocket")), count)
        (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
        x = max(2, min(x, img.shape[1] - tw - 4))
        y = min(y + h + 16, img.shape[0] - 4)
        cv2.rectangle(img, (x - 2, y - th - 3), (x + tw + 2, y + base), (0, 0, 0), -1)
        cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
        drawn += 1
    return drawn
