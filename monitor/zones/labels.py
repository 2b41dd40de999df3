"""Where text labels go in an image so that no two overlap: a pure placement, no drawing.

A zone label wants to sit just above its zone's outline; when zones are close (a robot box and
a camera's stop polygon around it) their labels would cover each other. Each label in turn takes
the free spot nearest to where it wants to be, moving down first, then sideways, then up,
never onto an earlier label or a reserved area (a header band, a legend).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

Rect = tuple[int, int, int, int]  # x1, y1, x2, y2 in pixels, half-open: [x1, x2) x [y1, y2)

# candidate columns are this many pixels apart when a label must move sideways
STEP_X_PX = 8


def intersects(a: Rect, b: Rect) -> bool:
    """True when the two rectangles share at least one pixel."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def place_labels(anchors: Sequence[tuple[float, float]], sizes: Sequence[tuple[int, int]],
                 width: int, height: int, reserved: Sequence[Rect] = (), gap: int = 2
                 ) -> list[Rect | None]:
    """One rectangle per label, in order, no two intersecting and none on ``reserved``.

    ``anchors``: where each label wants its top-left corner; ``sizes``: (w, h) of each label.
    Earlier labels are placed first and so sit nearest to their anchors (give the most
    important first). A label is moved down in steps of its height, then sideways in steps of
    ``STEP_X_PX``, then up, to the nearest free spot inside the image (downwards and sideways
    preferred: an upward move costs twice as much); ``gap`` pixels are kept between labels.
    None for a label that finds no free spot at all (an image too small for its labels).
    """
    taken = [_grow(r, gap) for r in reserved]
    out: list[Rect | None] = []
    for (ax, ay), (w, h) in zip(anchors, sizes, strict=True):
        w, h = int(w), int(h)
        if w > width or h > height:
            out.append(None)
            continue
        x0 = int(np.clip(round(ax), 0, width - w))
        y0 = int(np.clip(round(ay), 0, height - h))
        cand = _candidates(x0, y0, w, h, width, height, gap)
        free = _free(cand, w, h, taken)
        if not free.any():
            out.append(None)
            continue
        x, y = cand[int(np.argmax(free))]
        rect = (int(x), int(y), int(x) + w, int(y) + h)
        out.append(rect)
        taken.append(_grow(rect, gap))
    return out


def _grow(r: Rect, by: int) -> Rect:
    return (r[0] - by, r[1] - by, r[2] + by, r[3] + by)


def _candidates(x0: int, y0: int, w: int, h: int, width: int, height: int, gap: int
                ) -> np.ndarray:
    """(K, 2) top-left corners inside the image, nearest first: rows ``h + gap`` apart through
    the anchor, columns ``STEP_X_PX`` apart through it."""
    dy = h + gap
    ys = np.r_[np.arange(y0, height - h + 1, dy), np.arange(y0 - dy, -1, -dy)]
    xs = np.r_[np.arange(x0, width - w + 1, STEP_X_PX), np.arange(x0 - STEP_X_PX, -1,
                                                                 -STEP_X_PX)]
    gx, gy = np.meshgrid(xs, ys)
    gx, gy = gx.ravel(), gy.ravel()
    # rows count in label heights; sideways one label width costs one row; up costs double
    rows = (gy - y0) / dy
    cost = np.where(rows >= 0, rows, -2.0 * rows) + np.abs(gx - x0) / max(w, 1)
    order = np.lexsort((np.abs(gx - x0), cost))
    return np.c_[gx[order], gy[order]]


def _free(cand: np.ndarray, w: int, h: int, taken: Sequence[Rect]) -> np.ndarray:
    """(K,) bool: the ``w`` x ``h`` rectangle at each top-left corner of ``cand`` is free."""
    if not taken:
        return np.ones(len(cand), dtype=bool)
    t = np.asarray(taken, dtype=np.int64)
    x1, y1 = cand[:, :1], cand[:, 1:]
    hit = (x1 < t[:, 2]) & (t[:, 0] < x1 + w) & (y1 < t[:, 3]) & (t[:, 1] < y1 + h)
    return ~hit.any(axis=1)
