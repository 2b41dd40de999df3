"""The holds of lost persons as the pipeline sees them across its cameras: which lost persons
keep zones occupied (named as cell persons), and an operator's confirm-clear reset that drops
every hold of a *lost* person (docs/tracking.md)."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from dataclasses import replace

import cv2
import numpy as np

from monitor.health.objects import OBJECT_IN_ZONE
from monitor.pipeline.area_views import AreaView, UnseenView
from monitor.pipeline.data import CameraState
from monitor.pipeline.pocket_views import PocketView, in_counted, views_of
from monitor.policy import Command, Latch, ResetRequest, stale_latch
from monitor.policy.causes import stops
from monitor.policy.machine import CONFIRM_CLEAR_HINT
from monitor.tracking.cell_persons import CellPersons
from monitor.tracking.handover import HandedHolds
from monitor.tracking.tracks import Hold
from monitor.tracking.whereabouts import Whereabouts
from monitor.types import Alert, Fault
from monitor.zones import Cell
from monitor.zones.masks import zone_regions_px

log = logging.getLogger("monitor.pipeline")  # the pipeline's log, as before the split


def holds_of(cameras: Mapping[str, CameraState], persons: CellPersons
             ) -> dict[str, tuple[Hold, ...]]:
    """Per camera, the lost persons keeping zones occupied (named as cell persons)."""
    return {cid: tuple(persons.hold(cid, h) for h in cam.tracker.holds)
            for cid, cam in cameras.items() if cam.tracker}


def unseen_regions(cell: Cell | None, camera_id: str, where: Whereabouts,
                   cells: np.ndarray) -> list[str]:
    """The occluders and mask zones behind (or in) which the hidden ``cells`` of an area lie,
    by their ids; "a spot behind a fixture" when none of their outlines holds them (the
    robot base, or an uncalibrated view)."""
    grid = where.grid
    if grid is None or not cells.any():
        return []
    names: list[str] = []
    cam = cell.cameras.get(camera_id) if cell is not None else None
    if cell is not None and cam is not None:
        scale = np.array([cam.width / grid.width, cam.height / grid.height])
        pts = grid.centres()[cells.ravel()] * scale
        for zone, poly in zone_regions_px(cell, camera_id, ("occluder", "mask")):
            p = np.asarray(poly, np.float32).reshape(-1, 1, 2)
            if any(cv2.pointPolygonTest(p, (float(x), float(y)), False) >= 0
                   for x, y in pts):
                names.append(zone.id)
    return names or ["a spot behind a fixture"]


def pocket_views(cameras: Mapping[str, CameraState], cell: Cell | None,
                 named: dict[str, tuple[object, list[tuple[str, ...]]]] | None = None
                 ) -> tuple[PocketView, ...]:
    """Every camera's hidden pockets as the screen shows them (copies, read-only), with what
    hides each. ``named``: per camera, what hides its pockets as of the book's key (the
    pockets are found again only when that changes: naming them costs 0.6 ms a step)."""
    out: list[PocketView] = []
    named = {} if named is None else named
    for cid, cam in cameras.items():
        where = cam.tracker.where if cam.tracker is not None else None
        if where is None or where.grid is None or where.hidden is None:
            continue
        book = cam.tracker.pockets
        known = named.get(cid)
        if known is None or known[0] is not book.key or book.key is None:
            known = (book.key, [tuple(unseen_regions(cell, cid, where, p.cells))
                                for p in book.pockets])
            named[cid] = known
        out.extend(views_of(cid, book, where.grid.cell_px, (where.grid.width, where.grid.height),
                            known[1]))
    return tuple(out)


def area_views(cameras: Mapping[str, CameraState], persons: CellPersons, cell: Cell | None,
               pockets: tuple[PocketView, ...] = ()) -> tuple[AreaView, ...]:
    """Every lost person's area of every camera as the screen shows it (copies: the tracker
    goes on changing its own), with the unseen regions its hidden cells lie in and the
    counted ``pockets`` that hold them all (a person seen leaving can end it)."""
    out = []
    for cid, cam in cameras.items():
        where = cam.tracker.where if cam.tracker is not None else None
        if where is None or where.grid is None or where.hidden is None:
            continue
        grid = where.grid
        mine = [p for p in pockets if p.camera_id == cid]
        for tid, area in sorted(where.areas.items()):
            if not area.cells.any():
                continue
            hidden = area.cells & where.hidden
            regions = tuple(unseen_regions(cell, cid, where, hidden)) if hidden.any() else ()
            out.append(AreaView(cid, persons.who(cid, tid), tid, area.lost_since,
                                tuple(z.zone_id for z in area.zones), area.cells.copy(),
                                hidden, grid.cell_px, (grid.width, grid.height), regions,
                                tuple(p.pocket_id for p in in_counted(hidden, mine))))
    return tuple(out)


def unseen_views(cameras: Mapping[str, CameraState]) -> tuple[UnseenView, ...]:
    """Per camera with a tracker, the foot positions it cannot see a person at."""
    out = []
    for cid, cam in cameras.items():
        where = cam.tracker.where if cam.tracker is not None else None
        if where is None or where.grid is None or where.hidden is None:
            continue
        out.append(UnseenView(cid, where.hidden.copy(), where.grid.cell_px,
                              (where.grid.width, where.grid.height)))
    return tuple(out)


def remedies(cameras: Mapping[str, CameraState], persons: CellPersons, cell: Cell | None,
             clear_time: float) -> list[str]:
    """For every hold, what ends it: where its person may be that no camera sees, whether
    waiting ends it, and what does (the refusal of a reset says it)."""
    out = []
    for cid, cam in cameras.items():
        if cam.tracker is None:
            continue
        where = cam.tracker.where
        for h in cam.tracker.holds:
            area = where.areas.get(h.track_id)
            if area is None or where.hidden is None:
                continue
            who = persons.hold(cid, h).who or h.track_id
            hidden = area.cells & where.hidden
            counted = in_counted(hidden, views_of(cid, cam.tracker.pockets, 1.0, (1, 1)))
            if counted:
                out.append(_pocket_remedy(who, cid, counted,
                                          ", ".join(unseen_regions(cell, cid, where, hidden))))
            elif hidden.any():
                names = ", ".join(unseen_regions(cell, cid, where, hidden))
                brief = where.last_time is not None and where.last_time - h.lost_since \
                    <= cam.tracker.config.lost_track_s
                out.append(f"person {who} may be behind {names}, not seen by {cid} nor any "
                           "other camera: waiting does not end it; a second camera that sees "
                           "there" + (", the person seen walking out in clear view now"
                                      if brief else "")
                           + ", or `monitor reset --confirm-clear` after looking at the live "
                           "picture (also the console's Confirm clear, with the spot drawn) "
                           "does")
            else:
                until = h.lost_since + where.life_s(area)
                out.append(f"person {who} may be where {cid} sees: waiting ends it once {cid} "
                           f"has seen the zone free for {clear_time:g} s, at the latest "
                           f"{until - h.lost_since:.0f} s after the loss (a walker's time to "
                           "leave the picture); or `monitor reset --confirm-clear` after "
                           "looking at the live picture")
    return out


def _pocket_remedy(who, camera_id: str, counted: tuple[PocketView, ...], names: str) -> str:
    """What ends a hold whose hidden cells all lie in counted pockets: not waiting; each
    person seen walking out takes one off the count, and at 0 the area loses the pocket."""
    said = "; ".join(f"pocket {p.pocket_id}: " + (f"{p.count} may be inside" if p.count
                                                  else "counted empty")
                     for p in counted)
    return (f"person {who} may be behind {names} ({said}), not seen by {camera_id} nor any "
            "other camera: waiting does not end it; each person seen walking out of it takes "
            "one off its count, and at 0 the hold ends once the rest of its area is seen free, "
            "no confirm-clear needed; a second camera that sees there, or `monitor reset "
            "--confirm-clear` after looking at the live picture, also ends it")


def explain_refusal(command: Command, cameras: Mapping[str, CameraState],
                    persons: CellPersons, cell: Cell | None, clear_time: float) -> Command:
    """A reset refused for a lost person says what ends each hold (``remedies``) instead of
    the policy's general hint."""
    reset = command.reset
    hint = f" ({CONFIRM_CLEAR_HINT})"
    if reset is None or reset.accepted or hint not in reset.message:
        return command
    said = remedies(cameras, persons, cell, clear_time)
    if not said:
        return command
    message = reset.message.replace(hint, " (" + "; ".join(said) + ")")
    return replace(command, reset=replace(reset, message=message))


def cameras_in_fault(cameras: Mapping[str, CameraState], now: float,
                     extra: Iterable[Fault] = ()) -> list[str]:
    """Each camera that cannot show the cell now, with why: no frame yet, lost, a detector
    error, or a STOP fault of the camera or the detector in its newest frame (or in
    ``extra``, this step's own faults)."""
    extra = tuple(extra)
    out = []
    for cid, cam in cameras.items():
        why = None
        if cam.frame_time is None:
            why = "no frame yet"
        elif cam.detector_error:
            why = f"detector error: {cam.detector_error}"
        else:
            lost = cam.health.check_lost(now, cam.frame_time) if cam.health is not None \
                else None
            # an object standing in a zone since commissioning is no fault of the camera: it
            # shows the cell (the confirm-clear drops the holds outside the object's shadow;
            # the object itself is accepted by its own request, monitor.wire.object_accepts)
            bad = [f for f in (*cam.faults, *extra, *((lost,) if lost else ()))
                   if stops(f) and f.source in (cid, "detector") and f.name != OBJECT_IN_ZONE]
            if bad:
                why = f"{bad[0].name}: {bad[0].reason}"
        if why is not None:
            out.append(f"{cid} ({why})")
    return out


def confirm_clear(reset: ResetRequest | None, latched_by: Latch | None,
                  cameras: Mapping[str, CameraState], persons: CellPersons,
                  handover: HandedHolds | None, now: float,
                  extra: Iterable[Fault] = ()) -> tuple[tuple[Alert, ...], bool]:
    """An operator looked and confirms the cell clear: drop every hold of a *lost* person
    (seen persons keep their hits), before the policy judges the reset as usual. The
    cameras' trackers and zone answers (and the handed-over holds) change in place; the
    alert says what was dropped. Returns the alerts and whether the holds were dropped
    (the policy then judges the reset without them, also in a step without a frame).

    Refused, dropping nothing, while a camera is in fault (``cameras_in_fault``): the
    operator's look at the live picture is worth no more than the picture, and a camera in
    fault shows nothing (the policy refuses the reset for the fault too)."""
    if reset is None or not reset.confirm_clear:
        return (), False
    if stale_latch(reset, latched_by) is not None:
        return (), False  # made for another latch: the policy refuses it; it drops nothing
    faulty = cameras_in_fault(cameras, now, extra)
    if faulty:
        message = (f"operator {reset.operator}'s confirm-clear refused: a camera in fault "
                   f"cannot show the cell clear: {'; '.join(faulty)}; no hold dropped")
        log.warning(message)
        return (Alert("confirm_clear_refused", "warning", message, "pipeline", now, details={
            "operator": reset.operator, "request_id": reset.request_id, "note": reset.note,
            "cameras": faulty}),), False
    dropped: list[tuple[str, Hold]] = []
    for cid, cam in cameras.items():
        if cam.tracker is None:
            continue
        dropped.extend((cid, persons.hold(cid, h)) for h in cam.tracker.drop_holds())
        if cam.report is not None:
            cam.report = replace(cam.report, hits=tuple(h for h in cam.report.hits
                                                        if not h.lost))
    handed = handover.drop() if handover is not None else ()
    what = "; ".join([*(f"{cid}: {h.describe()}" for cid, h in dropped),
                      *(h.describe() for h in handed)]) or "no lost persons held"
    message = f"operator {reset.operator} confirmed the cell clear: dropped {what}"
    log.warning(message)
    return (Alert("confirm_clear", "warning", message, "pipeline", now, details={
        "operator": reset.operator, "request_id": reset.request_id, "note": reset.note,
        "dropped": [{"camera": cid, "person": h.who, "track_id": h.track_id,
                     "lost_since": h.lost_since,
                     "zones": [z.zone_id for z in h.zones]} for cid, h in dropped]}),), True
