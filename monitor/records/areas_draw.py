"""Drawing the lost persons' areas and the unseen foot positions onto a camera image: why the
cell is held, as the annotated replay, the console's live view and ``monitor zones preview``
show it (one look everywhere).

* an **unseen** foot position (behind an occluder, in a mask: no camera sees a person there)
  is hatched in ``UNSEEN_BGR``;
* a lost person's **area** (where they could be: ``monitor.pipeline.area_views``) is filled
  with ``AREA_BGR`` at ``AREA_ALPHA`` and outlined in it, and labelled with the person, the
  zones it holds and the unseen regions it reaches (waiting cannot end those);
* a hidden **pocket** (``monitor.pipeline.pocket_views``) is outlined in ``POCKET_BGR`` (its
  count unknown or above 0: held) or ``POCKET_FREE_BGR`` (counted empty) and labelled with its
  count below it (``pocket 1: 1 may be inside``).

The image may be any scale of the camera's frame (the console's live picture is smaller).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import cv2
import numpy as np

from monitor.pipeline.area_views import AreaView, UnseenView, cell_mask_px
from monitor.pipeline.pocket_views import PocketView, pocket_label

AREA_BGR = (0, 230, 255)  # yellow: none of the zone kinds' colours (monitor.zones.draw)
UNSEEN_BGR = (180, 0, 180)  # purple hatching (as `monitor zones preview` always drew it)
POCKET_BGR = (255, 255, 0)  # cyan: a pocket that may hold someone (none of the zones' colours)
POCKET_FREE_BGR = (80, 220, 80)  # green: a pocket counted empty
AREA_ALPHA = 0.45
FONT = cv2.FONT_HERSHEY_SIMPLEX


def hatch_cells(image: np.ndarray, cells: np.ndarray, cell_px: float,
                frame_size: tuple[int, int], colour=UNSEEN_BGR) -> int:
    """Cross-hatch each of ``cells`` (a grid over a ``frame_size`` frame) on ``image`` (any
    scale of that frame) in place, one cross a cell; returns how many cells. (One mask for
    all cells: a cell-by-cell drawing took 5-13 ms a frame with a few hundred hidden cells.)"""
    if not np.any(cells):
        return 0
    h, w = image.shape[:2]
    mask = cell_mask_px(cells, cell_px, frame_size, (w, h))
    step = max(4, round(cell_px * w / max(frame_size[0], 1)))
    image[mask & _hatch(h, w, step)] = colour
    return int(np.count_nonzero(cells))


@functools.lru_cache(maxsize=8)
def _hatch(h: int, w: int, step: int) -> np.ndarray:
    """(h, w) bool: diagonal lines both ways every ``step`` pixels (made once per image
    size: 30 ms at 1280x720 each frame otherwise)."""
    yy, xx = np.ogrid[0:h, 0:w]
    out = ((xx + yy) % step == 0) | ((xx - yy) % step == 0)
    out.setflags(write=False)
    return out


def draw_unseen(image: np.ndarray, views: Sequence[UnseenView], camera_id: str) -> int:
    """Hatch the foot positions ``camera_id`` cannot see (in place); how many cells."""
    return sum(hatch_cells(image, v.cells, v.cell_px, v.frame_size)
               for v in views if v.camera_id == camera_id)


def area_label(area: AreaView) -> str:
    """``person 6 may be here: holds prot (behind cabinet-2: waiting does not end it)``, or
    in a counted pocket ``... (behind cabinet-2, counted in pocket 1)``."""
    text = f"person {area.who} may be here"
    if area.zones:
        text += f": holds {', '.join(area.zones)}"
    if area.regions and area.leaving_ends:
        # the pocket's own label says its count (and so what a walk-out does)
        ids = ", ".join(str(p) for p in area.pockets)
        text += f" (behind {', '.join(area.regions)}, counted in pocket {ids})"
    elif area.regions:
        text += f" (behind {', '.join(area.regions)}: waiting does not end it)"
    return text


def pocket_colour(count: int | None) -> tuple[int, int, int]:
    """Green for a pocket counted empty, cyan for one that may hold someone (or unknown)."""
    return POCKET_FREE_BGR if count == 0 else POCKET_BGR


def draw_pockets(image: np.ndarray, pockets: Sequence[PocketView], camera_id: str,
                 avoid: Sequence[tuple[int, int, int, int]] = ()) -> tuple[str, ...]:
    """Outline each of ``camera_id``'s pockets on ``image`` (in place) in its colour and label
    it with its count just below it (clear of the ``avoid`` rectangles where it can be); the
    labels drawn."""
    h, w = image.shape[:2]
    labels = []
    for p in pockets:
        if p.camera_id != camera_id or not p.cells.any():
            continue
        mask = cell_mask_px(p.cells, p.cell_px, p.frame_size, (w, h)).view(np.uint8)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not contours:
            continue
        colour = pocket_colour(p.count)
        cv2.drawContours(image, contours, -1, colour, 2, cv2.LINE_AA)
        text = pocket_label(p)
        x, y0, _, bh = cv2.boundingRect(np.concatenate(contours))
        _text_on_black(image, text, (x, min(y0 + bh + 18, h - 4)), avoid, colour)
        labels.append(text)
    return tuple(labels)


def draw_areas(image: np.ndarray, areas: Sequence[AreaView], camera_id: str,
               top_px: int = 0, avoid: Sequence[tuple[int, int, int, int]] = ()
               ) -> tuple[str, ...]:
    """Fill and outline each of ``camera_id``'s areas on ``image`` (in place), label those that
    hold a zone (no higher than ``top_px``, clear of the ``avoid`` rectangles x1, y1, x2, y2
    where it can be); the labels drawn."""
    h, w = image.shape[:2]
    mine = [a for a in areas if a.camera_id == camera_id]
    if not mine:
        return ()
    union = np.zeros((h, w), np.uint8)
    masks = []
    for area in mine:
        mask = cell_mask_px(area.cells, area.cell_px, area.frame_size, (w, h)).view(np.uint8)
        masks.append(mask)
        union |= mask
    box = cv2.boundingRect(union)  # blend only where an area is (x, y, w, h)
    if box[2] and box[3]:
        x0, y0, bw, bh = box
        region = image[y0:y0 + bh, x0:x0 + bw]
        tinted = cv2.addWeighted(region, 1.0 - AREA_ALPHA,
                                 np.full_like(region, AREA_BGR), AREA_ALPHA, 0.0)
        inside = union[y0:y0 + bh, x0:x0 + bw].astype(bool)
        region[inside] = tinted[inside]
    labels = []
    for area, mask in zip(mine, masks, strict=True):
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(image, contours, -1, AREA_BGR, 2, cv2.LINE_AA)
        if not area.zones or not contours:
            continue  # an area that holds nothing is drawn, not explained
        text = area_label(area)
        x, y0, _, _ = cv2.boundingRect(np.concatenate(contours))
        y = max(y0 - 6, top_px + 16)
        _text_on_black(image, text, (x, min(y, h - 4)), avoid)
        labels.append(text)
    return tuple(labels)


def _text_on_black(img: np.ndarray, text: str, org: tuple[int, int],
                   avoid: Sequence[tuple[int, int, int, int]] = (), colour=AREA_BGR) -> None:
    """The label inside the image: moved left (and smaller) until it fits, and left of an
    ``avoid`` rectangle it would cover where there is room (else it stays: the label is
    worth more than what it covers)."""
    w = img.shape[1]
    scale = 0.5
    (tw, th), base = cv2.getTextSize(text, FONT, scale, 1)
    if tw > w - 8:
        scale *= (w - 8) / tw
        (tw, th), base = cv2.getTextSize(text, FONT, scale, 1)
    x, y = max(2, min(org[0], w - tw - 4)), org[1]
    for x1, y1, x2, y2 in avoid:
        if x < x2 and x + tw > x1 and y - th - 3 < y2 and y + base > y1:
            room = x1 - tw - 6
            if room >= 2:
                x = room
            else:  # no room beside it: smaller, ending left of it
                scale *= max(x1 - 8, 40) / tw
                (tw, th), base = cv2.getTextSize(text, FONT, scale, 1)
                x = max(2, x1 - tw - 6)
    cv2.rectangle(img, (x - 2, y - th - 3), (x + tw + 2, y + base), (0, 0, 0), -1)
    cv2.putText(img, text, (x, y), FONT, scale, colour, 1, cv2.LINE_AA)


KEY_ROWS = (("area", "lost person may be"), ("unseen", "unseen by camera"),
            ("pocket", "hidden pocket"))
_KEY_ROW_PX = 18
_KEY_WIDTH_PX = 150


def key_rect(width: int, top: int) -> tuple[int, int, int, int]:
    """Where the key of the areas' colours goes: the top-right corner, ``top`` px down (below
    the zone legend)."""
    return (width - _KEY_WIDTH_PX - 4, top, width - 4, top + 8 + _KEY_ROW_PX * len(KEY_ROWS))


def draw_key(img: np.ndarray, top: int) -> tuple[str, ...]:
    """The key (in place): a yellow swatch for a lost person's area, a purple hatch for the
    unseen floor; the rows' texts."""
    x1, y1, x2, y2 = key_rect(img.shape[1], top)
    cv2.rectangle(img, (x1, y1), (x2 - 1, y2 - 1), (0, 0, 0), -1)
    cv2.rectangle(img, (x1, y1), (x2 - 1, y2 - 1), (200, 200, 200), 1)
    texts = []
    for k, (kind, text) in enumerate(KEY_ROWS):
        y = y1 + 4 + k * _KEY_ROW_PX
        a, b = (x1 + 6, y + 3), (x1 + 26, y + _KEY_ROW_PX - 3)
        if kind == "area":
            cv2.rectangle(img, a, b, AREA_BGR, -1)
        elif kind == "pocket":
            cv2.rectangle(img, a, b, POCKET_BGR, 2)
        else:
            cv2.line(img, a, b, UNSEEN_BGR, 1, cv2.LINE_AA)
            cv2.line(img, (a[0], b[1]), (b[0], a[1]), UNSEEN_BGR, 1, cv2.LINE_AA)
        colour = {"area": AREA_BGR, "pocket": POCKET_BGR}.get(kind, (230, 130, 230))
        cv2.putText(img, text, (x1 + 32, y + _KEY_ROW_PX - 5), FONT, 0.45, colour, 1,
                    cv2.LINE_AA)
        texts.append(text)
    return tuple(texts)
