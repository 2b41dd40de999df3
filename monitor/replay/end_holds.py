"""The holds alive at the end of a scenario, judged against the ground truth (issue 46).

A hold alive after the last frame is **correct** when a person is really hidden somewhere its
area covers: their footprint (the bottom edge of their whole figure, hidden or not) touches
the area's cells while they are not seen (not drawn: a detector miss of the scene; or less
than ``HIDDEN_FRACTION`` of the figure in view: behind a fixture, behind another person). It is
a **ghost** otherwise: nobody hidden there (the person walked out in clear view, or was never
hidden). The count is of the last frame only: a hold that happens to cover a person the
detector misses in that frame counts as correct (a hold must be there then).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from monitor.pipeline.data import CameraState
from monitor.scene.cell import CellFrameTruth, CellScene, PersonState

# less of the figure than this in view: the person is not seen (a detector is not relied on
# to find a person showing less than half of themselves)
HIDDEN_FRACTION = 0.5


@dataclass(frozen=True)
class EndHold:
    """One hold alive after the last frame and the hidden persons its area covers."""

    camera_id: str
    track_id: int
    lost_since: float
    zones: tuple[str, ...]
    covers: tuple[int, ...]  # ground-truth person ids hidden within the area

    @property
    def correct(self) -> bool:
        return bool(self.covers)

    def describe(self) -> str:
        what = (f"correct (person {', '.join(map(str, self.covers))} hidden there)"
                if self.correct else "ghost (nobody hidden there)")
        return (f"{self.camera_id}: hold of track {self.track_id} lost at "
                f"{self.lost_since:.1f} s on {', '.join(self.zones)}: {what}")


def hidden_persons(truth: CellFrameTruth, scene: CellScene, missed: Iterable[int] = ()
                   ) -> tuple[PersonState, ...]:
    """The persons of the frame ``truth`` the camera does not see: not drawn (the scene's
    detector misses, ``missed`` frames shown empty) or less than ``HIDDEN_FRACTION`` of the
    figure in view."""
    gone = truth.index in set(missed)
    out = []
    for p in truth.persons:
        walker = scene.walkers[p.person_id]
        if gone or truth.index in walker.unseen_frames \
                or p.visible_fraction < HIDDEN_FRACTION:
            out.append(p)
    return tuple(out)


def judge_end_holds(cameras: Mapping[str, CameraState], hidden: Iterable[PersonState]
                    ) -> tuple[EndHold, ...]:
    """Every camera's holds as of now, each with the ``hidden`` persons whose footprint (the
    whole figure's bottom edge, half a cell of slack either side) touches its area."""
    hidden = [p for p in hidden if p.full_box_px is not None]
    out = []
    for cid, cam in cameras.items():
        tracker = cam.tracker
        if tracker is None:
            continue
        where = tracker.where
        for h in tracker.holds:
            area = where.areas.get(h.track_id)
            covers: list[int] = []
            if area is not None and where.grid is not None:
                for p in hidden:
                    x1, _, x2, y2 = (float(v) for v in p.full_box_px)  # type: ignore[misc]
                    feet = where.grid.cells_under(np.array([x1, y2 - 1.0, x2, y2]), 0.0,
                                                  band=1.0)
                    if (feet & area.cells).any():
                        covers.append(p.person_id)
            out.append(EndHold(cid, h.track_id, h.lost_since,
                               tuple(z.zone_id for z in h.zones), tuple(covers)))
    return tuple(out)
