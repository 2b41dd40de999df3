"""Operator mute requests on ``safety/mute``: the signed wire format, the bus-side gate and
the desk that holds requests until the pipeline has judged them (docs/muting.md).

Modelled on resets (``monitor.wire.resets``): a request is a Zenoh query whose payload is UTF-8
JSON and whose attachment is the Ed25519 signature (``monitor.wire.signing.signed_message(<mute
key>, payload)``) of an operator listed in the operators file. The bus refuses, before the
pipeline sees it and with a reason in the answer: an unknown operator, a missing or wrong
signature, another cell, another boot of the monitor (a request from before a restart), a
wall time more than ``window_s`` off the monitor's clock, a request id seen before. Muting is
never unsigned: a monitor without an operators file refuses every mute. The pipeline then
judges the zone's own rules (``monitor.cases.muting``: listed operators, maximum, unmutable) and its
outcome is the answer.

Every answer (accepted, refused, not judged; to a mute or to its ``end``) is signed with the
monitor's key and names the SHA-256 of the request it answers (``monitor.wire.answers``):
``monitor mute --monitor-key`` believes no rogue responder on the mute key (an "accepted" to
``--end`` the monitor never said would leave the operator believing the zone watched again).

Payload::

    {"schema": "workcell.safety.mute/1", "cell": "cell1", "zone": "robot-protective",
     "duration_s": 60, "end": false, "operator": "anna",
     "request_id": "anna-1732400000.123-5f3a", "wall": 1732400000.123, "boot": "4dee..."}
"""

from __future__ import annotations

import json
import time

from monitor.cases.muting import MuteOutcome, MuteRequest
from monitor.wire.answers import request_answer
from monitor.wire.request_desk import DeskRules, SignedRequestDesk
from monitor.wire.signed_requests import (
    RequestKind,
    SignedGate,
    load_request,
    new_request_id,
    number_fields,
    text_fields,
)
from monitor.wire.signing import Signer

MUTE_SCHEMA = "workcell.safety.mute/1"
MUTE_ANSWER_SCHEMA = "workcell.safety.mute-answer/1"
MAX_PAYLOAD = 4 * 1024
MAX_FIELD = 256


class MuteRefused(ValueError):
    """A mute request the bus refuses; the message is the reason told to the sender."""


MUTE = RequestKind("mute", "mutes", MuteRefused)


def mute_payload(operator: str, zone: str, duration_s: float, *, cell: str, boot: str,
                 end: bool = False, request_id: str = "", wall: float | None = None) -> bytes:
    """A mute request body (``end``: end the zone's mute now); ``request_id`` defaults to a
    fresh unique id, ``boot`` is the monitor's boot from its status."""
    wall = time.time() if wall is None else wall
    rid = request_id or new_request_id(operator, wall)
    return json.dumps({"schema": MUTE_SCHEMA, "cell": cell, "zone": zone,
                       "duration_s": duration_s, "end": end, "operator": operator,
                       "request_id": rid, "wall": wall, "boot": boot}).encode()


class MuteGate(SignedGate):
    """Checks the signature, cell, boot, clock window and request id of mute requests;
    remembers request ids (not thread-safe: ``MuteDesk`` holds the lock)."""

    kind = MUTE

    def parse(self, payload: bytes) -> dict:
        return _parse(payload)

    def request(self, body: dict, received: float) -> MuteRequest:
        """A MuteRequest (``time`` = ``received``)."""
        return MuteRequest(body["zone"], body["operator"], body["duration_s"],
                           body["request_id"], received, end=body["end"], wall=body["wall"])


def _parse(payload: bytes) -> dict:
    noun = "mute request"
    body = load_request(payload, MAX_PAYLOAD, MUTE_SCHEMA, noun, MuteRefused)
    out = text_fields(body, ("operator", "request_id", "zone", "cell", "boot"), MAX_FIELD, noun,
                      MuteRefused)
    out.update(number_fields(body, ("duration_s", "wall"), noun, MuteRefused))
    end = body.get("end", False)
    if not isinstance(end, bool):
        raise MuteRefused("mute request with a malformed end")
    out["end"] = end
    return out


MUTE_DESK = DeskRules(MuteRefused, "malformed mute request", "mute_refused", "mute",
                      MUTE_ANSWER_SCHEMA, MAX_PAYLOAD)


class MuteDesk(SignedRequestDesk):
    """The bus's side of muting (``monitor.wire.request_desk``): verified requests wait here
    for the pipeline (``poll``), their queries until it has judged them (``answer``) or
    ``answer_s`` passed; requests refused here are answered at once and alerted
    (``drain_alerts``). Thread-safe. Its answers are signed by ``signer`` (the monitor's key)
    and name the request and the monitor (``who``: instance, boot)."""

    def __init__(self, gate: MuteGate, answer_s: float = 2.0, signer: Signer | None = None,
                 who: dict | None = None) -> None:
        super().__init__(gate, MUTE_DESK, answer_s, signer, who)

    def judged(self, outcome: MuteOutcome) -> dict:
        """The zone, and for a mute in force its length and what is left of it."""
        body: dict = {"zone": outcome.request.zone}
        mute = outcome.mute
        if mute is not None:
            body["duration_s"] = mute.end - mute.start
            body["ends_in_s"] = max(mute.end - outcome.request.time, 0.0)
        return body


# the answer to a signed request: one mechanism for every kind (monitor/wire/answers.py)
request_mute = request_answer
