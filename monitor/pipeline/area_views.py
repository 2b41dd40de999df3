"""What the screen shows of the lost persons' areas: plain, frozen copies handed on with each
step (``StepResult.areas``, ``StepResult.unseen``) so that the annotated replay, the console's
live view and ``monitor zones preview`` draw why the cell is held without reaching into the
tracker (``monitor.tracking.whereabouts`` keeps the live ones).

Cells are foot positions on the camera's grid (``FootGrid``): cell ``(j, i)`` covers the image
pixels ``[i * cell_px, (i + 1) * cell_px) x [j * cell_px, (j + 1) * cell_px)`` of the camera's
frame. ``outlines_px`` turns a set of cells into image polygons (the console's payload).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class AreaView:
    """Where one lost person could be, as of one step, on one camera."""

    camera_id: str
    who: int | str  # the person as the commands name them (the cell person, else the track)
    track_id: int
    lost_since: float  # capture time of the last frame the person was seen in
    zones: tuple[str, ...]  # the protective/warning zones it holds (empty: it holds none)
    cells: np.ndarray  # (ny, nx) bool: where the person could be standing
    hidden: np.ndarray  # (ny, nx) bool: those of ``cells`` no camera can see
    cell_px: float  # a cell's side in the camera frame's pixels
    frame_size: tuple[int, int]  # (w, h) of the camera frame the grid covers
    regions: tuple[str, ...] = ()  # the unseen regions its hidden cells lie in (occluder ids)
    # the counted pockets (monitor.pipeline.pocket_views) that hold every hidden cell of it,
    # by id; empty when a hidden cell lies elsewhere or in a pocket of unknown count
    pockets: tuple[int, ...] = ()

    @property
    def waiting_ends(self) -> bool:
        """Whether waiting can end it: an area with no hidden cell ends once its cells are
        seen free (or at its bounded life); a hidden cell is never seen free."""
        return not bool(self.hidden.any())

    @property
    def leaving_ends(self) -> bool:
        """Whether a person seen walking out can end it: its hidden cells all lie in counted
        pockets, whose cells it loses once their count is down to 0 (each person seen
        leaving takes one off); waiting still does not."""
        return bool(self.pockets) and not self.waiting_ends


@dataclass(frozen=True)
class UnseenView:
    """The foot positions one camera cannot see a person at (behind an occluder, in a mask):
    a lost person's area there is never seen free by this camera."""

    camera_id: str
    cells: np.ndarray  # (ny, nx) bool
    cell_px: float
    frame_size: tuple[int, int]  # (w, h) of the camera frame the grid covers


def cell_mask_px(cells: np.ndarray, cell_px: float, frame_size: tuple[int, int],
                 size: tuple[int, int]) -> np.ndarray:
    """(h, w) bool over an image of ``size`` (w, h), a copy of the camera's ``frame_size``
    frame at any scale: the pixels the ``cells`` cover. (OpenCV's nearest-neighbour resize of
    the grid to the image pixels it spans, cut to the image: 0.2 ms at 1280x720 where a
    numpy gather took 4.6.)"""
    w, h = int(size[0]), int(size[1])
    ny, nx = cells.shape
    span_w = max(1, round(nx * cell_px * w / max(frame_size[0], 1)))
    span_h = max(1, round(ny * cell_px * h / max(frame_size[1], 1)))
    big = cv2.resize(np.asarray(cells, np.uint8), (max(span_w, w), max(span_h, h)),
                     interpolation=cv2.INTER_NEAREST) if (span_w >= w and span_h >= h) else \
        _padded(cv2.resize(np.asarray(cells, np.uint8), (span_w, span_h),
                           interpolation=cv2.INTER_NEAREST), w, h)
    return big[:h, :w].astype(bool)


def _padded(mask: np.ndarray, w: int, h: int) -> np.ndarray:
    """``mask`` grown to at least (h, w) by repeating its last row and column."""
    return cv2.copyMakeBorder(mask, 0, max(0, h - mask.shape[0]), 0, max(0, w - mask.shape[1]),
                              cv2.BORDER_REPLICATE)


def outlines_px(cells: np.ndarray, cell_px: float) -> list[list[list[float]]]:
    """The outer outlines of ``cells`` as polygons in the camera frame's pixels (cell
    corners; holes are not cut out: the outline is where the area ends)."""
    mask = np.asarray(cells, np.uint8)
    if not mask.any():
        return []
    # one pixel per cell, padded: a contour follows cell centres; corners are at +-0.5
    big = cv2.resize(mask, (mask.shape[1] * 2, mask.shape[0] * 2),
                     interpolation=cv2.INTER_NEAREST)
    contours, _ = cv2.findContours(big, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = []
    for c in contours:
        pts = c.reshape(-1, 2).astype(np.float64)
        # half-cells -> frame pixels; the contour runs along the inner edge of the last pixel
        pts = (pts + (pts % 2 == 1)) * (cell_px / 2.0)
        out.append([[round(float(x), 1), round(float(y), 1)] for x, y in pts])
    return out


def areas_body(areas: tuple[AreaView, ...], unseen: tuple[UnseenView, ...], camera_id: str
               ) -> dict:
    """The detections message's share of one camera's areas (the console draws them): each
    area's outline in the camera frame's pixels, the person, the zones it holds, the unseen
    regions it reaches, whether waiting can end it, and whether a person seen leaving can (the
    counted pockets holding its hidden cells); and the outline of what the camera cannot see
    (the pockets are ``monitor.pipeline.pocket_views.pockets_body``'s)."""
    return {
        "areas": [{"person": a.who, "track_id": a.track_id, "lost_since": a.lost_since,
                   "zones": list(a.zones), "regions": list(a.regions),
                   "waiting_ends": a.waiting_ends, "leaving_ends": a.leaving_ends,
                   "pockets": list(a.pockets),
                   "outlines_px": outlines_px(a.cells, a.cell_px),
                   "hidden_px": outlines_px(a.hidden, a.cell_px)}
                  for a in areas if a.camera_id == camera_id],
        "unseen_px": [poly for v in unseen if v.camera_id == camera_id
                      for poly in outlines_px(v.cells, v.cell_px)],
    }
