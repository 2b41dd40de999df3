"""Two persons in one box: when a box that held two persons shows one, the other is somewhere.

A detector boxes two persons walking side by side as one (0.80 as wide as tall with the
synthetic model), and ByteTrack gives that box one track. When one of them steps behind a
cabinet the box narrows to the other and the track goes on: no track is lost, so no area would
be kept where the person who stepped out could be (``monitor.tracking.whereabouts``). Width
alone does not say "two persons": a single walker's stride makes the box as wide for a frame
or two (0.80 at 10 fps, every few frames), and an area for every stride cost refused resets
and ghost holds (docs/tracking.md, "A box that held two persons").

The evidence used here is in the image:

* **Two heads** (a camera with a commissioning reference): in a band ``HEAD_BAND`` of the
  box height from the box's top changed row (looked for in its top ``SEARCH_BAND``), the
  frame differs from the reference (the empty cell) in columns; a head is a run of changed
  columns at least ``HEAD_MIN`` of the box height wide, two such runs with the
  reference's background between them are two heads. A walker's stride spreads the legs,
  never the head: one run (arms are a column or two and do not count).
* **Wide from the first sighting** (no reference, or the head band cannot be compared): a
  track seen too wide for one person at every sighting since its first, at least
  ``WIDE_SIGHTINGS`` of them; a walker is seen narrow now and then.

A track with that evidence that then shows one head (or, without heads, narrows) has lost a
person: the tracker keeps an area of their own where the box stood at its last two-person
sighting, under a new person number with no ByteTrack link, so no sighting of the track ends
it by the name link (``PersonTracker._split_from``). Not when another box of the same frame
stands where the box was (the pair parted in view: both are seen). The area ends as any
other (seen free, the bounded life, a pocket's count, a confirm-clear), and when the pair is
seen as two again soon after (within ``lost_track_s``): the track that kept the box seen by
its own association and a new box within a walk of where the pair stood that can only have
come from floor the camera shows (``out_in_view``: a person the detector missed for a frame
beside their colleague, not one who stepped out from behind a fixture or another person).

Pure numpy/OpenCV on small crops (the head band of each box), a few tens of microseconds a box.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from monitor.tracking.whereabouts import FootGrid, grow

HEAD_BAND = 0.15  # the share of a person's height that shows their head, from its top
SEARCH_BAND = 0.4  # the top of a box where the head's top is looked for
HEAD_MIN = 0.05  # a head is at least this wide for the box height (synthetic: 0.10)
CHANGE = 30.0  # grey levels (largest channel) after the lighting fit: as the objects watch
SINGLE_WIDTH = 0.7  # a box wider than this for its height may hold two (``pockets``)
WIDE_SIGHTINGS = 2  # without heads: wide this many sightings from the first, then narrow
UNKNOWN = -1  # heads that could not be counted (no reference, box off the image)


def heads_in_boxes(image_bgr: np.ndarray | None, reference_bgr: np.ndarray | None,
                   boxes_px: np.ndarray) -> np.ndarray:
    """(N,) int: the heads seen in the head band of each box (``UNKNOWN`` without a
    reference of the same size, or where the band lies off the image)."""
    boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
    out = np.full(len(boxes), UNKNOWN, np.int64)
    if image_bgr is None or reference_bgr is None or image_bgr.shape != reference_bgr.shape:
        return out
    for i, box in enumerate(boxes):
        out[i] = _heads(image_bgr, reference_bgr, box)
    return out


def _heads(image: np.ndarray, reference: np.ndarray, box: np.ndarray) -> int:
    """Runs of changed columns in the box's head band at least a head wide; the band starts
    at the box's top changed row (a detector's box often starts above the head)."""
    h_img, w_img = image.shape[:2]
    x1, y1, x2, y2 = (float(v) for v in box)
    if not np.all(np.isfinite(box)) or x2 - x1 < 2 or y2 - y1 < 8:
        return UNKNOWN
    height = y2 - y1
    a, b = round(max(x1, 0.0)), round(min(x2, float(w_img)))
    top, bottom = round(y1), round(y1 + SEARCH_BAND * height)
    if top < 0 or bottom > h_img or b - a < 2 or bottom - top < 4:
        return UNKNOWN  # the head band is cut by the image border: nothing to count
    # the lighting fitted on the band's background, half a box width either side included
    # (a light dimmed since commissioning changes nothing)
    m = round(0.5 * (x2 - x1))
    ca, cb = max(a - m, 0), min(b + m, w_img)
    cur = image[top:bottom, ca:cb].astype(np.float32)
    ref = reference[top:bottom, ca:cb].astype(np.float32)
    changed = (np.abs(cur - _fit(cur, ref)).max(axis=2) > CHANGE)[:, a - ca:b - ca]
    rows = np.flatnonzero(changed.sum(axis=1) >= 2)
    if not len(rows):
        return UNKNOWN  # nothing where a head would be: no evidence either way
    band = changed[rows[0]:rows[0] + max(2, round(HEAD_BAND * height))]
    columns = band.sum(axis=0) >= max(2, 0.25 * len(band))
    return sum(1 for n in _runs(columns) if n >= max(3.0, HEAD_MIN * height)) or UNKNOWN


def _fit(cur: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """The reference as the frame's lighting shows it: gain and offset fitted on the pixels
    a median offset already explains (a head does not bend the fit)."""
    x, y = ref.ravel().astype(np.float64), cur.ravel().astype(np.float64)
    offset = float(np.median(y - x))
    use = np.abs(y - x - offset) < 2 * CHANGE
    gain = 1.0
    if use.sum() >= 30:
        xs, ys = x[use], y[use]
        var = float(xs.var())
        if var >= 25.0:
            gain = min(max(float(np.cov(xs, ys, bias=True)[0, 1]) / var, 0.5), 2.0)
        offset = float(ys.mean() - gain * xs.mean())
    return gain * ref + offset


def _runs(changed: np.ndarray) -> list[int]:
    """Lengths of the runs of True, a single False column inside a run bridged (noise)."""
    out: list[int] = []
    run, gap = 0, 0
    for c in changed.tolist():
        if c:
            run, gap = run + gap + 1, 0
        elif run:
            gap += 1
            if gap > 1:
                out.append(run)
                run, gap = 0, 0
    if run:
        out.append(run)
    return out


def narrow(box: np.ndarray) -> bool:
    """No wider than one person for its height (``SINGLE_WIDTH``)."""
    x1, y1, x2, y2 = (float(v) for v in np.asarray(box, np.float64).reshape(4))
    return x2 - x1 <= SINGLE_WIDTH * max(y2 - y1, 1.0)


@dataclass
class _PairState:
    two_heads: np.ndarray | None = None  # the box of the last sighting with two heads
    counted: bool = False  # heads were counted at some sighting (then width says nothing)
    wide_box: np.ndarray | None = None  # the last box while wide at every sighting so far
    wide_run: int = 0  # sightings, all wide, since the first (-1: seen narrow once)


@dataclass
class PairWatch:
    """Per track of one camera: whether its box is known to hold two persons."""

    tracks: dict[int, _PairState] = field(default_factory=dict)

    def seen(self, track_id: int, box: np.ndarray, heads: int) -> np.ndarray | None:
        """The track seen with ``box`` showing ``heads``; the box it had when it last held two
        persons when it holds one now (a person stepped out of it), else None."""
        s = self.tracks.setdefault(track_id, _PairState())
        box = np.asarray(box, np.float64).reshape(4).copy()
        stepped = None
        if heads != UNKNOWN:
            s.counted = True
            if heads >= 2:
                s.two_heads = box
            elif s.two_heads is not None:
                stepped, s.two_heads = s.two_heads, None
        elif s.two_heads is None and not s.counted and s.wide_run >= 0:
            if not narrow(box):
                s.wide_run, s.wide_box = s.wide_run + 1, box
            else:
                if s.wide_run >= WIDE_SIGHTINGS:
                    stepped = s.wide_box
                s.wide_run, s.wide_box = -1, None
        return stepped

    def forget(self, track_id: int) -> None:
        self.tracks.pop(track_id, None)


def seen_beside(stepped_box: np.ndarray, row: int, boxes_px: np.ndarray) -> bool:
    """Another box of this frame than ``row`` stands where the two-person box was (at least
    half of its width within that box's columns, overlapping its rows): the pair parted in
    view, the other one is seen."""
    x1, y1, x2, y2 = (float(v) for v in np.asarray(stepped_box, np.float64).reshape(4))
    for i, (a, b, c, d) in enumerate(np.asarray(boxes_px, np.float64).reshape(-1, 4)):
        if i == row or d <= y1 or b >= y2:
            continue
        if min(c, x2) - max(a, x1) >= 0.5 * max(c - a, 1.0):
            return True
    return False


@dataclass(frozen=True)
class Split:
    """An area kept for the person who stepped out of a two-person box (``area_id``), the
    track that kept the box (``track_id``), where the box held both and when it was split."""

    area_id: int
    track_id: int
    box: np.ndarray
    since: float


def out_in_view(grid: FootGrid, hidden: np.ndarray, box: np.ndarray,
                others_before: np.ndarray, reach_cells: int,
                frame_size: tuple[int, int], edge_px: float) -> bool:
    """A box whose person can only have come from floor the camera shows: off the image
    border, its feet on cells the camera sees, and its walk since the previous frame
    (``reach_cells``) reaches no hidden cell and no cell under another person of the
    previous frame (``others_before``: someone may have been hidden behind them)."""
    w, h = frame_size
    x1, y1, x2, y2 = (float(v) for v in np.asarray(box, np.float64).reshape(4))
    if not (x1 > edge_px and y1 > edge_px and x2 < w - edge_px and y2 < h - edge_px):
        return False
    feet = grid.cells_under(np.array([x1, y1, x2, y2]), 0.0)
    came = grow(feet, reach_cells)
    return not (came & hidden).any() and not (came & others_before).any()
