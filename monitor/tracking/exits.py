"""A lost person seen walking out of their area: the person appearing where only they could
have been is them (issue 46: a flickering detector's box that comes back under a new id, or
under the old one given back by the tracker's nearness guess).

A lost person's area is everywhere they could be (``monitor.tracking.whereabouts``). When a
person *appears* (a box not seen in the camera's previous frame), every place they could have
stood in that previous frame (their feet cells grown by a walk since then) held nobody the
monitor knows of but the lost one: it lay in that one area, or the camera, working, showed it
with nobody there (the areas never grow into such floor either: nobody the camera could see
was there). So they came out of the area, and the area ends ("seen coming out"), whatever id
the tracker gives the box: its id is a name, where the person came from is the evidence (as
for the hidden pockets' exits, ``monitor.tracking.pockets``).

It is no exit (the area stays) when anyone else may have been there too:

* a place they could have come from is hidden (behind a fixture), under a person seen in the
  previous frame (someone may walk hidden right behind them), at the image border (from off
  the picture), not shown by the camera in the previous frame (a fault, a detector error), or
  in another lost person's area (either may have come out);
* the area reaches a hidden cell (someone else may be behind the fixture and have stepped
  into the area's open part unseen), was joined from two losses, or its last box may have
  held two persons (too wide for one and the track not known as one:
  ``PocketBook.single``);
* the appearing box is not in clear view (at the image border, feet on hidden cells, another
  box over it: its feet may be hidden behind that one);
* two appearing persons could both have come out of the area (one person is never two).

A place a merged track stood (``LostArea.behind``) counts as one lost person's area here: the
rule asks where the person came from, not who they are. Judged on the previous frame's view
(before this frame's update), as the pockets' exits.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from monitor.tracking.foot_grid import FootGrid, grow
from monitor.tracking.whereabouts import LostArea, Whereabouts

# a single person's box is at most this wide for their height (monitor.tracking.pockets)
SINGLE_WIDTH = 0.7
# a box this close to the image border: a person may have stepped in from off the picture
EDGE_PX = 8.0


def came_out(where: Whereabouts, boxes_px: np.ndarray, appearing: Iterable[int], now: float,
             single: set[int] | frozenset[int] = frozenset()) -> dict[int, int]:
    """Lost track id -> the row of this frame's boxes seen coming out of its area (see the
    module's rules). ``appearing``: rows not seen in the previous frame; ``single``: tracks
    known as one person."""
    grid, occupied = where.grid, where.occupied_now()
    if grid is None or where.free_since is None or occupied is None or where.hidden is None \
            or where.last_time is None or not where.areas:
        return {}
    free = ~np.isnan(where.free_since)  # seen free in the previous frame
    boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
    dt = max(0.0, now - where.last_time)
    candidates = {tid: a for tid, a in where.areas.items() if _one_person(a, where, single)}
    claims: dict[int, list[int]] = {}
    for row in appearing:
        box = boxes[row]
        if not _clear_view(box, row, boxes, grid, where.hidden):
            continue
        came = grow(grid.cells_under(box, 0.0), _steps(where, box, dt, grid))
        if came[0, :].any() or came[-1, :].any() or came[:, 0].any() or came[:, -1].any():
            continue  # from off the picture, perhaps
        if (came & where.hidden).any() or (came & occupied).any() or (came & ~free).any():
            continue  # from behind a fixture or a seen person (anyone may have been there),
            # or from where the camera could not judge
        owners = [tid for tid, a in where.areas.items() if (came & a.cells).any()]
        if len(owners) != 1 or owners[0] not in candidates:
            continue  # from nobody's area (a person the detector missed), or from two
        claims.setdefault(owners[0], []).append(row)
    return {tid: rows[0] for tid, rows in claims.items() if len(rows) == 1}


def _one_person(area: LostArea, where: Whereabouts, single: set[int] | frozenset[int]
                ) -> bool:
    """The area is one person's, all in view: not joined from two losses, reaching no hidden
    cell, its last box narrow enough for one person (or the track known as one)."""
    if area.merged or where.hidden is None or (area.cells & where.hidden).any():
        return False
    x1, _, x2, _ = area.box_px
    return x2 - x1 <= SINGLE_WIDTH * max(area.box_height_px, 1.0) or area.track_id in single


def _clear_view(box: np.ndarray, row: int, boxes: np.ndarray, grid: FootGrid,
                hidden: np.ndarray) -> bool:
    """In clear view: off the image border, its feet on cells the camera sees, no other box
    of the frame overlapping it (its feet may be hidden behind that one). It may be wider
    than one person: whoever is in it came from where the area's person was."""
    x1, y1, x2, y2 = (float(v) for v in box)
    if not (x1 > EDGE_PX and y1 > EDGE_PX and x2 < grid.width - EDGE_PX
            and y2 < grid.height - EDGE_PX):
        return False
    if (grid.cells_under(box, 0.0) & hidden).any():
        return False
    others = np.delete(boxes, row, axis=0)
    if not len(others):
        return True
    w = np.minimum(x2, others[:, 2]) - np.maximum(x1, others[:, 0])
    h = np.minimum(y2, others[:, 3]) - np.maximum(y1, others[:, 1])
    return not bool(((w > 0) & (h > 0)).any())


def _steps(where: Whereabouts, box: np.ndarray, dt: float, grid: FootGrid) -> int:
    """Cells a person of this box walks in ``dt`` (as the areas grow), at least one."""
    cfg = where.config
    h = max(float(box[3] - box[1]), 1.0)
    reach = cfg.walk_speed_mps / cfg.height_m * h * cfg.reach_margin * dt
    return max(1, math.ceil(min(reach / grid.cell_px, grid.nx + grid.ny)))
