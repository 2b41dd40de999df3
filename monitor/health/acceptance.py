"""An operator's acceptance of objects that appeared since commissioning, judged against what
the cameras see now (the signed request and its bus checks: ``monitor.wire.object_accepts``),
and what the status says of the changed cell.

The request names a camera and a zone; every object that camera found standing in that zone
and nobody accepted yet is accepted by it (an operator looks at a zone, not at pixel boxes).
Bad input is one line in the answer: an unknown camera, a camera without a commissioning
reference (nothing is compared there), an unknown zone, no object standing there. Accepted or
refused, an alert records who asked for what and when: the events file is the audit.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from monitor.health.objects import SceneObject, ZoneObjects
from monitor.types import Alert
from monitor.wire.object_accepts import AcceptOutcome, ObjectAccept, accept_command

OBJECT_ACCEPTED = "object_accepted"
OBJECT_ACCEPT_REFUSED = "object_accept_refused"


def judge_accept(watches: Mapping[str, ZoneObjects], camera_ids: Sequence[str],
                 zone_ids: Sequence[str], req: ObjectAccept, now: float
                 ) -> tuple[AcceptOutcome, Alert]:
    """Accept the objects ``req`` names (``watches``: each camera's object check;
    ``camera_ids``, ``zone_ids``: the cell's) or refuse in one line; the outcome and its
    alert."""
    reason = _bad_input(watches, camera_ids, zone_ids, req)
    if reason is None:
        accepted = watches[req.camera].accept(req.zone, req.operator, now, req.wall)
        if accepted:
            return _accepted(req, accepted, now)
        reason = _nothing_there(watches[req.camera], req)
    details = {"operator": req.operator, "request_id": req.request_id, "camera": req.camera,
               "zone": req.zone, "wall": req.wall, "accepted": False}
    return (AcceptOutcome(req, False, reason),
            Alert(OBJECT_ACCEPT_REFUSED, "warning", f"acceptance by {req.operator} of an "
                  f"object in zone {req.zone} on {req.camera} refused: {reason}", "objects",
                  now, details=details))


def _bad_input(watches: Mapping[str, ZoneObjects], camera_ids: Sequence[str],
               zone_ids: Sequence[str], req: ObjectAccept) -> str | None:
    if req.camera not in camera_ids:
        return f"unknown camera {req.camera!r} (this monitor's: {', '.join(camera_ids)})"
    if req.zone not in zone_ids:
        return (f"unknown zone {req.zone!r} (protective and warning zones: "
                f"{', '.join(zone_ids) or 'none'})")
    if req.camera not in watches:
        return (f"camera {req.camera} has no commissioning reference: no objects are watched "
                "there, none to accept")
    return None


def _nothing_there(watch: ZoneObjects, req: ObjectAccept) -> str:
    there = [o for o in watch.objects.values() if req.zone in o.zone_ids]
    if there:
        who = ", ".join(sorted({str(o.accepted_by) for o in there}))
        return f"the object in {there[0].place()} is already accepted (by {who})"
    others = sorted({z for o in watch.objects.values() for z in o.zone_ids})
    return (f"no object stands in zone {req.zone} on camera {req.camera}"
            + (f" (objects stand in: {', '.join(others)})" if others else ""))


def _accepted(req: ObjectAccept, accepted: list[SceneObject], now: float
              ) -> tuple[AcceptOutcome, Alert]:
    objects = tuple(object_record(req.camera, o) for o in accepted)
    what = "; ".join(o.place() for o in accepted)
    reason = (f"accepted by {req.operator}: the object in {what} on {req.camera} is now an "
              "occluder declared at run time (the floor behind it stays unseen: a person lost "
              "there is held until seen free); the cell has changed since commissioning")
    alert = Alert(OBJECT_ACCEPTED, "warning", f"{req.camera}: {reason}", "objects", now, details={
                      "operator": req.operator, "request_id": req.request_id,
                      "camera": req.camera, "zone": req.zone, "note": req.note,
                      "wall": req.wall, "accepted": True, "objects": list(objects)})
    return AcceptOutcome(req, True, reason, objects), alert


def object_record(camera_id: str, obj: SceneObject) -> dict:
    """One object as the status and the alerts give it (JSON-able)."""
    return {"camera": camera_id, "zones": list(obj.zone_ids), "place": obj.place(),
            "floor_m": list(obj.floor_m) if obj.floor_m else None, "box_px": list(obj.box_px),
            "protective": obj.protective, "accepted_by": obj.accepted_by,
            "accepted_wall": obj.accepted_wall,
            "accept": None if obj.accepted_by else accept_command(camera_id, obj.zone_ids[0])}


def changed_cell(watches: Mapping[str, ZoneObjects]) -> list[dict]:
    """What the status says of the cell since commissioning: every object standing now."""
    return [object_record(cid, o) for cid, w in sorted(watches.items())
            for o in sorted(w.objects.values(), key=lambda o: o.object_id)]


def changed_signature(watches: Mapping[str, ZoneObjects]) -> tuple:
    """Changes whenever an object appears, goes, moves or is accepted (status updates)."""
    return tuple((cid, w.version, tuple((o.object_id, o.accepted_by) for o in
                                        w.objects.values())) for cid, w in sorted(watches.items()))

