"""Hidden pockets with a count: a hidden region enclosed by seen floor is a room.

A lost person's area that reaches hidden cells stays there (``monitor.tracking.whereabouts``):
nobody sees behind the cabinet, so only a confirm-clear or another camera ends it. But a
hidden region that is *enclosed by seen floor* (behind a cabinet in the middle of the
picture, not at the image edge, not next to other unseen space) can only be entered and left
across floor the camera sees. Such a region is a *pocket*, and a pocket can keep a count of the
persons who may be inside:

* the count starts **unknown** (held as today: an area that reaches it stays until a
  confirm-clear or another camera's view),
* a confirm-clear sets it to **0** (the operator looked, every camera working),
* every **entry** counts: a lost person's area reaching the pocket adds the persons its box
  may hold (a box too wide for one person, or one that swallowed another track: unknown),
* every **exit** counts: a person appearing at the pocket's border who can only have come out
  of it takes one off (never one that may have come from anywhere else unseen: from behind
  another person, off the image edge, a spot not seen free, another hidden region),
* at **0** the pocket is free: the lost persons' areas lose its cells and end once the rest
  is seen free, no second confirm-clear needed.

Anything that makes the count doubtful makes it unknown again (held as today): a frame the
camera cannot judge (a STOP fault, a detector error), a person coming out of a pocket counted
empty (an entry was missed), the hidden cells changing (a zone swap, an object put down).

The count is an upper bound, never an estimate: an exit is counted only when nobody else can
have been where the person came from, and a track's loss is counted once per pocket until the
track is seen again. A person who walks in wholly hidden behind another person, and was never
seen alone, is not counted (as everywhere in the monitor: a person the camera never sees is
not tracked; docs/tracking.md, "Hidden pockets").

Pure numpy on the camera's foot grid; the state is a plain dataclass others can draw (the
console, the zones preview): each pocket's cells, count and why it is what it is.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np

from monitor.tracking.whereabouts import FootGrid, LostArea, Whereabouts, grow

# a single person's box is at most this wide for their height (a walking figure, arms out, as
# a coarse detector boxes it: the synthetic model gives 0.61; two persons shoulder to shoulder
# 0.81): a wider box may hold two persons side by side, its entry is of unknown size
SINGLE_WIDTH = 0.7
WIDE = -1  # in ``PocketBook.carrying``: the track's box was seen too wide for one person
# a box this close to the image border: a person may have joined it from off the picture
EDGE_PX = 8.0


@dataclass
class Pocket:
    """One enclosed hidden region of a camera's foot grid and the persons who may be in it."""

    pocket_id: int
    cells: np.ndarray  # (ny, nx) bool, cells of the camera's FootGrid
    count: int | None = None  # persons who may be inside; None: unknown (held as today)
    entered: set[int] = field(default_factory=set)  # tracks whose loss has been counted
    why: str = "unknown since the start"  # what made the count what it is (said, drawn)
    since: float = math.nan  # capture time of the last change

    @property
    def free(self) -> bool:
        return self.count == 0

    def describe(self) -> str:
        what = "unknown" if self.count is None else str(self.count)
        return f"pocket {self.pocket_id}: {what} inside ({self.why})"


@dataclass
class PocketBook:
    """The pockets of one camera, as of its newest frame."""

    pockets: list[Pocket] = field(default_factory=list)
    # the hidden cells (the array itself) and whether the floor was known when found
    key: tuple[object, bool] | None = None
    # track id -> the track ids whose boxes merged into it since (``WIDE``: its box was seen
    # too wide for one person): a box that may hold two persons
    carrying: dict[int, set[int]] = field(default_factory=dict)
    changes: list[str] = field(default_factory=list)  # said since the last ``take_changes``
    # the cells under the persons seen in the newest frame (feet band and below): someone
    # may stand hidden right behind them, so nobody stepping out of there is an exit
    occupied: np.ndarray | None = None
    # tracks seen as one person: narrow, feet in view, off the image border, carrying nobody;
    # nobody has joined their box since (no track lost into it, not at the image border), so
    # a wider box later is the person's stride, not a second person (``seen``)
    single: set[int] = field(default_factory=set)

    def take_changes(self) -> list[str]:
        out, self.changes = self.changes, []
        return out


def find_pockets(hidden: np.ndarray, floor: np.ndarray | None = None) -> list[np.ndarray]:
    """The enclosed hidden regions: 8-connected hidden cells that touch no image border and
    whose ring of neighbours is all floor the camera can see (``floor``: cells whose foot
    position lies on the floor, None: all). A region open to the image edge or to floor that
    is not seen (above the horizon, off the floor) is no pocket."""
    hidden = np.asarray(hidden, bool)
    if not hidden.any():
        return []
    n, labels = cv2.connectedComponents(hidden.astype(np.uint8), connectivity=8)
    out = []
    for label in range(1, n):
        cells = labels == label
        if cells[0, :].any() or cells[-1, :].any() or cells[:, 0].any() or cells[:, -1].any():
            continue  # open to the image edge: a person may come and go unseen
        ring = grow(cells, 1) & ~cells
        if floor is not None and not np.asarray(floor, bool)[ring].all():
            continue
        out.append(cells)
    return out


def refresh(book: PocketBook, where: Whereabouts, now: float) -> None:
    """The pockets of the camera's hidden cells, found again (every count unknown) when the
    hidden cells changed (another zone set, an object put down, another image size) or the
    floor became known (the first frame of a calibrated camera)."""
    if where.hidden is None or where.grid is None:
        return
    floor = where.floor_cells()
    key = (where.hidden, floor is not None)
    if book.key is not None and book.key[0] is key[0] and book.key[1] == key[1]:
        return
    why = "unknown since the start" if book.key is None \
        else "unknown since the hidden cells changed"
    book.pockets = [Pocket(k + 1, c, None, set(), why, now)
                    for k, c in enumerate(find_pockets(where.hidden, floor))]
    book.key = key


def unknown(book: PocketBook, why: str, now: float) -> None:
    """The camera could not judge a frame: nobody knows who went in or out meanwhile."""
    for p in book.pockets:
        if p.count is not None:
            _set(book, p, None, why, now)


def confirm(book: PocketBook, now: float) -> None:
    """An operator confirmed the cell clear (every camera working): every pocket is empty.
    A person seen now and stepping in later is counted in once lost."""
    book.carrying.clear()
    for p in book.pockets:
        p.entered.clear()
        _set(book, p, 0, "confirm-clear", now)


def settle(book: PocketBook, where: Whereabouts, now: float) -> None:
    """Once the areas have grown (``Whereabouts.update``'s ``settle``): the pockets of the
    hidden cells (``refresh``), then the entries (``count_entries``)."""
    refresh(book, where, now)
    count_entries(book, where, now)


def seen(book: PocketBook, where: Whereabouts, track_ids: Iterable[int],
         boxes_px: np.ndarray) -> None:
    """Tracks seen in this frame: a box too wide for one person may carry two (until the
    track is seen narrow with its feet in view), unless the track is known as one person
    (``PocketBook.single``: a walker's box widens with the stride, 0.81 of its height at
    5 fps with the synthetic model, as wide as two persons shoulder to shoulder); one that
    swallowed another track is no longer thought to carry it once that one is seen on its
    own."""
    ids = list(track_ids)
    boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
    for into in list(book.carrying):
        book.carrying[into] -= set(ids)
        if not book.carrying[into]:
            del book.carrying[into]
    grid, hidden = where.grid, where.hidden
    book.occupied = None if grid is None else grid.cells_under(boxes, where.config.below)
    for tid, (x1, y1, x2, y2) in zip(ids, boxes, strict=True):
        narrow = x2 - x1 <= SINGLE_WIDTH * max(y2 - y1, 1.0)
        feet_seen = grid is not None and hidden is not None \
            and not (grid.cells_under(np.array([x1, y1, x2, y2]), 0.0) & hidden).any()
        _single(book, tid, (x1, y1, x2, y2), narrow and feet_seen, grid)
        if not narrow:
            if tid not in book.single:
                book.carrying.setdefault(tid, set()).add(WIDE)
        elif tid in book.carrying and feet_seen:
            book.carrying[tid].discard(WIDE)
            if not book.carrying[tid]:
                del book.carrying[tid]


def _single(book: PocketBook, track_id: int, box: tuple[float, float, float, float],
            one: bool, grid: FootGrid | None) -> None:
    """Whether the track is known as one person after this sighting: it is once seen narrow
    with its feet in view (``one``), off the image border and carrying no other track; it is
    no longer once its box touches the image border (a person may have stepped in beside it
    from off the picture). A track lost into its box ends it too (``swallowed``). A person
    joining from hidden floor has an area of their own, counted in on its own."""
    x1, y1, x2, y2 = box
    if grid is None or x1 <= EDGE_PX or y1 <= EDGE_PX or x2 >= grid.width - EDGE_PX \
            or y2 >= grid.height - EDGE_PX:
        book.single.discard(track_id)
    elif one and not (book.carrying.get(track_id, set()) - {WIDE}):
        book.single.add(track_id)


def lost(book: PocketBook, track_id: int) -> None:
    """A track lost again: its next entry into a pocket is a new one (a loss is counted once
    per pocket, however long its area lingers at the pocket's border)."""
    for p in book.pockets:
        p.entered.discard(track_id)


def swallowed(book: PocketBook, track_id: int, into: int) -> None:
    """``track_id`` was lost inside the box of ``into``: that box may hold both."""
    book.carrying.setdefault(into, set()).update({track_id, *book.carrying.pop(track_id, ())})
    book.single.discard(into)


def count_exits(book: PocketBook, where: Whereabouts, boxes_px: np.ndarray,
                appearing: Iterable[int], now: float) -> None:
    """Persons appearing in this frame (rows not seen in the camera's previous frame) who can
    only have come out of a pocket: one off its count each (at most one a pocket a frame: one
    person may be seen as two boxes). Judged on the previous frame, before this frame's
    update: where the person could have come from since then (their feet cells grown by a
    walk) must lie within the pocket, the cells seen free for clear_time, and the areas of
    lost persons the pocket has counted in; else it is no exit (someone else may have been
    there). Out of a pocket counted empty: an entry was missed, the count is unknown."""
    grid, free = where.grid, where.free_now()
    if grid is None or free is None or where.last_time is None or where.hidden is None:
        return
    counted = [p for p in book.pockets if p.count is not None]
    if not counted:
        return
    dt = max(0.0, now - where.last_time)
    boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
    done: set[int] = set()
    for row in appearing:
        box = boxes[row]
        feet = grid.cells_under(box, 0.0)
        came = grow(feet, _steps(where, box, dt, grid))
        if came[0, :].any() or came[-1, :].any() or came[:, 0].any() or came[:, -1].any():
            continue  # from off the image, perhaps
        for p in counted:
            if p.pocket_id in done or not (came & p.cells).any():
                continue
            allowed = free | p.cells
            for area in where.areas.values():
                if area.track_id in p.entered:
                    allowed = allowed | area.cells
            if book.occupied is not None and book.occupied.shape == allowed.shape:
                # under a person seen in the previous frame: a counted-in person's area may
                # have grown there, but so may anyone hidden behind that person
                allowed = allowed & ~book.occupied
            if (came & ~allowed).any():
                continue  # someone else may have been there: no exit
            done.add(p.pocket_id)
            if p.count == 0:
                _set(book, p, None, "a person came out of it while counted empty", now)
            else:
                _set(book, p, p.count - 1, "a person came out", now)


def count_entries(book: PocketBook, where: Whereabouts, now: float) -> None:
    """After the areas grew: every lost person's area reaching a counted pocket is an entry
    (once per track until it is seen again), of the persons its box may hold; a box too wide
    for one person, or one that swallowed another track, makes the count unknown. A pocket
    counted empty takes its cells off every area (nobody is in there)."""
    for p in book.pockets:
        if p.count is None:
            continue
        for area in where.areas.values():
            if (area.cells & p.cells).any() and not _enter(book, p, area, now):
                break
        if p.count == 0:
            for area in where.areas.values():
                if (area.cells & p.cells).any():
                    area.cells &= ~p.cells
                    if not area.cells.any():
                        area.ended_by = "pocket counted empty"


def _enter(book: PocketBook, p: Pocket, area: LostArea, now: float) -> bool:
    """``area`` reaches counted pocket ``p``: its tracks not counted in yet go in, as many
    persons as its box may hold. False when that made the count unknown."""
    ids = {area.track_id, *area.merged} - p.entered
    if not ids or p.count is None:
        return p.count is not None
    p.entered |= ids
    x1, _, x2, _ = area.box_px
    wide = (x2 - x1) > SINGLE_WIDTH * max(area.box_height_px, 1.0) \
        and not ids <= book.single
    carried = set().union(*(book.carrying.get(t, set()) for t in ids)) - p.entered
    if wide or carried:
        _set(book, p, None, f"person {area.track_id} went in, perhaps with someone beside "
             "or behind them", now)
        return False
    _set(book, p, p.count + len(ids), f"person {area.track_id} went in", now)
    return True


def _steps(where: Whereabouts, box: np.ndarray, dt: float, grid: FootGrid) -> int:
    """Cells a person of this box walks in ``dt`` (as the areas grow), at least one."""
    cfg = where.config
    h = max(float(box[3] - box[1]), 1.0)
    reach = cfg.walk_speed_mps / cfg.height_m * h * cfg.reach_margin * dt
    return max(1, math.ceil(min(reach / grid.cell_px, grid.nx + grid.ny)))


def _set(book: PocketBook, p: Pocket, count: int | None, why: str, now: float) -> None:
    if count == p.count and why == p.why:
        return
    p.count, p.why, p.since = count, why, now
    book.changes.append(p.describe())
