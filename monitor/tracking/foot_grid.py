"""The foot grid over a camera's image: square cells, each standing for feet at its centre,
where the lost persons' areas live (``monitor.tracking.whereabouts``) and the hidden pockets
are found (``monitor.tracking.pockets``): the cells under a box's feet band, where a person
hidden in a neighbour's box may stand, and growth by a walk. Pure numpy and OpenCV."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

# the lowest share of a person's box where the feet of a person hidden right behind them may
# be (two persons whose boxes merge stand within about half a metre of each other)
FEET_BAND = 0.35


@dataclass(frozen=True)
class FootGrid:
    """Square cells over a ``width`` x ``height`` image; a cell stands for feet at its centre."""

    width: int
    height: int
    cell_px: float
    nx: int
    ny: int

    @classmethod
    def of(cls, width: int, height: int, across: int) -> FootGrid:
        cell = max(float(width) / max(int(across), 1), 1.0)
        return cls(int(width), int(height), cell, max(1, math.ceil(width / cell)),
                   max(1, math.ceil(height / cell)))

    @property
    def shape(self) -> tuple[int, int]:
        return self.ny, self.nx

    def centres(self) -> np.ndarray:
        """(ny * nx, 2) pixel centres, row by row."""
        xs = (np.arange(self.nx) + 0.5) * self.cell_px
        ys = (np.arange(self.ny) + 0.5) * self.cell_px
        gx, gy = np.meshgrid(xs, ys)
        return np.c_[gx.ravel(), gy.ravel()]

    def cells_under(self, boxes_px: np.ndarray, below: float, band: float = FEET_BAND
                    ) -> np.ndarray:
        """(ny, nx) bool: cells where the feet of a person with one of these boxes, or of one
        hidden right behind them, may be: the lowest ``band`` of the box (a person further
        behind shows their head above it to a camera mounted above head height), half a
        cell wider, and ``below`` of its height under its bottom edge."""
        out = np.zeros(self.shape, dtype=bool)
        c = self.cell_px
        for x1, y1, x2, y2 in np.asarray(boxes_px, np.float64).reshape(-1, 4):
            if not all(map(math.isfinite, (x1, y1, x2, y2))):
                return np.ones(self.shape, dtype=bool)  # a box that says nothing: anywhere
            h = max(y2 - y1, 0.0)
            i0, i1 = _span(x1 - 0.5 * c, x2 + 0.5 * c, c, self.nx)
            j0, j1 = _span(y2 - band * h, y2 + below * h + 0.5 * c, c, self.ny)
            out[j0:j1, i0:i1] = True
        return out


def carried_cells(grid: FootGrid, lost_box_px: np.ndarray, carrier_box_px: np.ndarray,
                  reach_px: float, below: float) -> np.ndarray:
    """(ny, nx) bool: where the feet of a person hidden in a seen neighbour's box (the
    carrier) may be: across the carrier's columns (walking with it), at the hidden person's
    own depth (the feet rows of their last box: the lowest ``FEET_BAND`` and ``below``
    under it) grown by ``reach_px`` (the walk since the loss, in pixels), and never outside
    the carrier's own rows (``below`` under it included): hidden by it. A person lost 6 m
    behind a passer-by walks on 6 m behind them, not at their feet (the carrier's feet band
    put a person lost on the far side of the protective zone into it, issue 46). Rows
    that miss the carrier: its own feet band (``cells_under``)."""
    lx1, ly1, lx2, ly2 = (float(v) for v in np.asarray(lost_box_px, np.float64).reshape(4))
    cx1, cy1, cx2, cy2 = (float(v) for v in np.asarray(carrier_box_px, np.float64).reshape(4))
    lh, ch = max(ly2 - ly1, 0.0), max(cy2 - cy1, 0.0)
    reach = max(float(reach_px), 0.0) if math.isfinite(reach_px) else math.inf
    top = max(ly2 - FEET_BAND * lh - reach, cy1)
    bottom = min(ly2 + below * lh + reach, cy2 + below * ch)
    if not all(map(math.isfinite, (lx1, ly1, lx2, ly2, cx1, cy1, cx2, cy2))) or top > bottom:
        return grid.cells_under(carrier_box_px, below)
    return grid.cells_under(np.array([cx1, top, cx2, bottom]), 0.0, band=1.0)


def _span(lo: float, hi: float, cell: float, n: int) -> tuple[int, int]:
    """Cells whose centre lies in [lo, hi] (at least the cell containing lo..hi's middle)."""
    a = max(0, math.ceil(lo / cell - 0.5))
    b = min(n, math.floor(hi / cell - 0.5) + 1)
    if b <= a:  # narrower than a cell: the cell under the middle
        mid = min(max(int((lo + hi) * 0.5 / cell), 0), n - 1)
        return mid, mid + 1
    return a, b


_KERNEL = np.ones((3, 3), np.uint8)


def grow(cells: np.ndarray, steps: int) -> np.ndarray:
    """``cells`` grown by ``steps`` cells in every direction (8 neighbours a step: a square,
    more than a walk of that many cells in any direction, never less)."""
    if steps <= 0 or not cells.any():
        return cells.copy()
    return cv2.dilate(cells.astype(np.uint8), _KERNEL, iterations=int(steps)).astype(bool)
