"""An operator's acceptance of an object that appeared in a zone since commissioning, on
``<prefix>safety/objects/accept``: the signed wire format and the bus-side gate
(docs/occlusion.md, "Objects since commissioning").

An object standing in a protective zone that the commissioning reference does not show holds
the cell in STOP (``object_in_zone``) and refuses every reset until an operator has looked at
it and accepts it, by its own request, never as a side effect of a reset: ``monitor objects
accept --camera cam0 --zone robot-protective``. Accepted, the object becomes an occluder
declared at run time (the floor behind it stays unseen, a person lost there stays held until
seen free); the reset is then judged as usual.

Modelled on mutes (``monitor.cases.mute_requests``): a Zenoh query whose payload is UTF-8 JSON
and whose attachment is the Ed25519 signature (``monitor.wire.signing.signed_message(<accept
key>, payload)``) of an operator listed in the operators file. The bus refuses, before the
pipeline sees it and with one line in the answer: an unknown operator, a missing or wrong
signature, another cell, another boot of the monitor, a wall time more than ``window_s`` off
the monitor's clock, a request id seen before (``monitor.wire.signed_requests``). Never
unsigned: a monitor without an operators file refuses every acceptance (even one that allows
unsigned resets in the lab). The pipeline then judges whether there is such an object
(``monitor.health.acceptance``) and its outcome is the answer.

Payload::

    {"schema": "workcell.safety.object-accept/1", "cell": "cell1", "camera": "cam0",
     "zone": "robot-protective", "operator": "anna", "note": "crate of parts, looked behind",
     "request_id": "anna-1732400000.123-5f3a", "wall": 1732400000.123, "boot": "4dee..."}
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass

from monitor.wire.signed_requests import (
    RequestKind,
    SignedGate,
    load_request,
    new_request_id,
    number_fields,
    text_fields,
)

ACCEPT_SCHEMA = "workcell.safety.object-accept/1"
ACCEPT_ANSWER_SCHEMA = "workcell.safety.object-accept-answer/1"
MAX_PAYLOAD = 4 * 1024
MAX_FIELD = 256


class AcceptRefused(ValueError):
    """An acceptance the bus refuses; the message is the reason told to the sender."""


ACCEPT = RequestKind("object acceptance", "object acceptances", AcceptRefused)


def accept_command(camera: str, zone: str) -> str:
    """The command that accepts an object (named by every refusal an object causes)."""
    return f"monitor objects accept --camera {camera} --zone {zone}"


@dataclass(frozen=True)
class ObjectAccept:
    """A verified acceptance request. ``time``: when it arrived (the monitor's monotonic
    clock); ``wall``: the sender's Unix time (checked within the window of the monitor's)."""

    operator: str
    camera: str
    zone: str
    request_id: str
    time: float
    wall: float
    note: str = ""


@dataclass(frozen=True)
class AcceptOutcome:
    """The pipeline's judgement of one acceptance (the answer to its query)."""

    request: ObjectAccept
    accepted: bool
    reason: str
    objects: tuple[dict, ...] = ()  # the objects accepted: camera, zones, floor_m, box_px


def accept_payload(operator: str, camera: str, zone: str, *, cell: str, boot: str,
                   note: str = "", request_id: str = "", wall: float | None = None) -> bytes:
    """An acceptance request body; ``request_id`` defaults to a fresh unique id, ``boot`` is
    the monitor's boot from its status."""
    wall = time.time() if wall is None else wall
    rid = request_id or new_request_id(operator, wall)
    return json.dumps({"schema": ACCEPT_SCHEMA, "cell": cell, "camera": camera, "zone": zone,
                       "operator": operator, "note": note, "request_id": rid, "wall": wall,
                       "boot": boot}).encode()


class AcceptGate(SignedGate):
    """Checks signature, cell, boot, clock window and request id of acceptances; remembers
    request ids (not thread-safe: the bus's desk holds a lock)."""

    kind = ACCEPT

    def parse(self, payload: bytes) -> dict:
        return _parse(payload)

    def request(self, body: dict, received: float) -> ObjectAccept:
        """An ObjectAccept (``time`` = ``received``)."""
        return ObjectAccept(body["operator"], body["camera"], body["zone"], body["request_id"],
                            received, body["wall"], body["note"])


def _parse(payload: bytes) -> dict:
    noun = "object acceptance"
    body = load_request(payload, MAX_PAYLOAD, ACCEPT_SCHEMA, noun, AcceptRefused)
    out = text_fields(body, ("operator", "request_id", "camera", "zone", "cell", "boot"),
                      MAX_FIELD, noun, AcceptRefused)
    out.update(number_fields(body, ("wall",), noun, AcceptRefused))
    note = body.get("note", "")
    if not isinstance(note, str) or len(note) > 4 * MAX_FIELD:
        raise AcceptRefused("object acceptance with a malformed note")
    out["note"] = note
    return out
