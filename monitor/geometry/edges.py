"""What the commissioning reference says about cut-off feet: its long horizontal edges.

A person standing behind a bench, a cabinet front or a low wall shows the body above it, and
the detector's box ends on the fixture's top edge. In the reference image of the empty cell
(``monitor reference capture``) that edge is a long, roughly horizontal brightness step. A box
whose lower edge lies on such an edge may have its feet hidden, whether the fixture is declared
in the zone file or not (``monitor.geometry.occlusion.feet_may_be_hidden``): it is then placed
from the head over the whole height range, towards the camera, as a short box is.

Pure functions over images; nothing here reads files.
"""

from __future__ import annotations

import cv2
import numpy as np

# a brightness step of at least this much (0..255, the largest of the colour channels) between
# the rows above and below counts as an edge: a bench top against the floor behind it is far
# more; sensor noise (sigma 2) and a floor's gradient far less
EDGE_CONTRAST = 24.0
# an edge at least this share of the image width long (and 8 px at least): a fixture's top,
# not a bolt head or the texture of a floor
EDGE_MIN_RUN_FRACTION = 1.0 / 40.0
# how far above and below an edge its two sides are compared (px, and a share of the image
# height, the larger): farther than a floor marking is wide
LINE_REACH_PX = 12
LINE_REACH_FRACTION = 1.0 / 40.0


def horizontal_edges(reference_bgr: np.ndarray, contrast: float = EDGE_CONTRAST,
                     min_run_px: int | None = None) -> np.ndarray:
    """(H, W) bool: pixels on a long, roughly horizontal edge of the reference image.

    An edge pixel has a vertical brightness step of ``contrast`` or more (any colour channel,
    3x3 Sobel) that is at least twice its horizontal step, lies on a run of such pixels at
    least ``min_run_px`` long (a slope of a pixel per run is allowed), and parts two different
    surfaces (not a thin line on the floor: the colours a little above and below differ)."""
    img = np.asarray(reference_bgr)
    if img.ndim == 2:
        img = img[..., None]
    h, w = img.shape[:2]
    run = max(8, round(w * EDGE_MIN_RUN_FRACTION)) if min_run_px is None else int(min_run_px)
    data = img.astype(np.float32)
    gy = np.abs(cv2.Sobel(data, cv2.CV_32F, 0, 1, ksize=3)).reshape(h, w, -1).max(axis=2)
    gx = np.abs(cv2.Sobel(data, cv2.CV_32F, 1, 0, ksize=3)).reshape(h, w, -1).max(axis=2)
    # a Sobel step response is 4x the step
    strong = ((gy >= 4.0 * contrast) & (gy >= 2.0 * gx)).astype(np.uint8)
    # a slanted edge steps a row now and then: join rows, then keep the long horizontal runs
    joined = cv2.dilate(strong, np.ones((3, 1), np.uint8))
    long_runs = cv2.morphologyEx(joined, cv2.MORPH_OPEN, np.ones((1, run), np.uint8)) > 0
    # a thin line on the floor (a painted marking, a tile seam) has the same floor above and
    # below it: not the top of anything. A fixture's top edge parts two surfaces (the floor or
    # wall behind, the fixture's own face): keep only edges whose colours ``reach`` px above
    # and below differ by ``contrast`` too
    reach = max(LINE_REACH_PX, round(h * LINE_REACH_FRACTION))
    above = np.zeros_like(data)
    below = np.zeros_like(data)
    above[reach:] = data[:-reach]
    below[:-reach] = data[reach:]
    parts = np.abs(above - below).reshape(h, w, -1).max(axis=2) >= contrast
    parts[:reach] = parts[-reach:] = True  # at the image border: cannot tell, keep
    return long_runs & parts
