"""What the screen shows of the hidden pockets (``monitor.tracking.pockets``): plain, frozen
copies handed on with each step (``StepResult.pockets``) so that the annotated replay and the
console draw why the cell is held behind a cabinet and what will end it, without reaching into
the tracker. Read-only: building a view never changes a count.

A pocket's label says its count in the user's words (``pocket_label``):

* ``pocket 1: unknown (held until confirm-clear)``: nobody knows who is inside; a lost
  person's area reaching it stays until a confirm-clear (or another camera's view);
* ``pocket 1: 2 may be inside``: counted since a confirm-clear; each person seen walking out
  takes one off, at 0 the areas lose its cells;
* ``pocket 1: empty (counted)``: counted to 0, nobody is in there.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from monitor.pipeline.area_views import AreaView, UnseenView, areas_body, outlines_px
from monitor.tracking.pockets import PocketBook


@dataclass(frozen=True)
class PocketView:
    """One hidden pocket of one camera, as of one step."""

    camera_id: str
    pocket_id: int
    cells: np.ndarray  # (ny, nx) bool, cells of the camera's foot grid
    count: int | None  # persons who may be inside; None: unknown (held)
    why: str  # what made the count what it is ("confirm-clear", "person 3 went in", ...)
    cell_px: float  # a cell's side in the camera frame's pixels
    frame_size: tuple[int, int]  # (w, h) of the camera frame the grid covers
    regions: tuple[str, ...] = ()  # what hides it (occluder ids), when known

    @property
    def counted(self) -> bool:
        """Counted since a confirm-clear: a person seen walking out of it takes one off."""
        return self.count is not None


def pocket_label(view: PocketView) -> str:
    """``pocket 1: unknown (held until confirm-clear)``, ``pocket 1: 1 may be inside``,
    ``pocket 1: empty (counted)``."""
    return pocket_text(view.pocket_id, view.count)


def pocket_text(pocket_id: int | str, count: int | None) -> str:
    """A pocket's label from its id and count (None: unknown), as every screen says it."""
    if count is None:
        what = "unknown (held until confirm-clear)"
    elif count == 0:
        what = "empty (counted)"
    else:
        what = f"{count} may be inside"
    return f"pocket {pocket_id}: {what}"


def views_of(camera_id: str, book: PocketBook, cell_px: float, frame_size: tuple[int, int],
             regions: Iterable[tuple[str, ...]] = ()) -> tuple[PocketView, ...]:
    """Copies of a camera's pockets (``regions``: what hides each, in the book's order)."""
    names = list(regions)
    return tuple(PocketView(camera_id, p.pocket_id, p.cells.copy(), p.count, p.why, cell_px,
                            frame_size, names[k] if k < len(names) else ())
                 for k, p in enumerate(book.pockets))


def in_counted(hidden: np.ndarray, pockets: Iterable[PocketView]) -> tuple[PocketView, ...]:
    """The counted pockets holding every one of the ``hidden`` cells of an area (empty when
    any hidden cell lies outside a counted pocket: then no walk-out ends it)."""
    hidden = np.asarray(hidden, bool)
    if not hidden.any():
        return ()
    mine = tuple(p for p in pockets if p.counted and (p.cells & hidden).any())
    rest = hidden.copy()
    for p in mine:
        rest &= ~p.cells
    return () if rest.any() else mine


def pockets_body(pockets: Iterable[PocketView], camera_id: str) -> list[dict]:
    """The detections message's share of one camera's pockets (the console lists and draws
    them): id, count (None: unknown), why, what hides it, the label and the outline in the
    camera frame's pixels."""
    return [{"pocket": p.pocket_id, "count": p.count, "why": p.why,
             "regions": list(p.regions), "label": pocket_label(p),
             "outlines_px": outlines_px(p.cells, p.cell_px)}
            for p in pockets if p.camera_id == camera_id]


def screen_body(areas: tuple[AreaView, ...], unseen: tuple[UnseenView, ...],
                pockets: tuple[PocketView, ...], camera_id: str) -> dict:
    """The detections message's share of why one camera's cell is held: the lost persons'
    areas and the unseen floor (``areas_body``) and the pockets (``pockets_body``)."""
    return {**areas_body(areas, unseen, camera_id), "pockets": pockets_body(pockets, camera_id)}
