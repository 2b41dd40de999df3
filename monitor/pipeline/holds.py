"""The holds of lost persons as the pipeline sees them across its cameras: which lost persons
keep zones occupied (named as cell persons), and an operator's confirm-clear reset that drops
every hold of a *lost* person (docs/tracking.md)."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import replace

from monitor.pipeline.data import CameraState
from monitor.policy import Latch, ResetRequest, stale_latch
from monitor.tracking.cell_persons import CellPersons
from monitor.tracking.handover import HandedHolds
from monitor.tracking.tracks import Hold
from monitor.types import Alert

log = logging.getLogger("monitor.pipeline")  # the pipeline's log, as before the split


def holds_of(cameras: Mapping[str, CameraState], persons: CellPersons
             ) -> dict[str, tuple[Hold, ...]]:
    """Per camera, the lost persons keeping zones occupied (named as cell persons)."""
    return {cid: tuple(persons.hold(cid, h) for h in cam.tracker.holds)
            for cid, cam in cameras.items() if cam.tracker}


def confirm_clear(reset: ResetRequest | None, latched_by: Latch | None,
                  cameras: Mapping[str, CameraState], persons: CellPersons,
                  handover: HandedHolds | None, now: float) -> tuple[Alert, ...]:
    """An operator looked and confirms the cell clear: drop every hold of a *lost* person
    (seen persons keep their hits), before the policy judges the reset as usual. The
    cameras' trackers and zone answers (and the handed-over holds) change in place; the
    alert says what was dropped."""
    if reset is None or not reset.confirm_clear:
        return ()
    if stale_latch(reset, latched_by) is not None:
        return ()  # made for another latch: the policy refuses it; it may drop nothing
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
                     "zones": [z.zone_id for z in h.zones]} for cid, h in dropped]}),)
