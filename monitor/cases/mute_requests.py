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

Payload::

    {"schema": "workcell.safety.mute/1", "cell": "cell1", "zone": "robot-protective",
     "duration_s": 60, "end": false, "operator": "anna",
     "request_id": "anna-1732400000.123-5f3a", "wall": 1732400000.123, "boot": "4dee..."}
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import time

from monitor.cases.muting import MuteOutcome, MuteRequest
from monitor.wire import payload as payload_json
from monitor.wire.answers import request_answer
from monitor.wire.request_desk import DeskRules, SignedRequestDesk
from monitor.wire.signed_requests import RequestKind, SignedGate

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
    rid = request_id or f"{operator}-{wall:.3f}-{os.urandom(3).hex()}"
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
    if len(payload) > MAX_PAYLOAD:
        raise MuteRefused("mute request too large")
    try:
        body = payload_json.load(payload, MAX_PAYLOAD)
    except payload_json.PayloadError as exc:
        raise MuteRefused(f"mute request refused: {exc}") from None
    if not isinstance(body, dict) or body.get("schema") != MUTE_SCHEMA:
        raise MuteRefused(f"mute request is not a {MUTE_SCHEMA} object")
    out = {}
    for key in ("operator", "request_id", "zone", "cell", "boot"):
        value = body.get(key)
        if not isinstance(value, str) or not value.strip() or len(value) > MAX_FIELD:
            raise MuteRefused(f"mute request without a valid {key}")
        out[key] = value.strip() if key == "operator" else value
    for key in ("duration_s", "wall"):
        value = body.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not _finite(value):
            raise MuteRefused(f"mute request without a valid {key}")
        out[key] = float(value)
    end = body.get("end", False)
    if not isinstance(end, bool):
        raise MuteRefused("mute request with a malformed end")
    out["end"] = end
    return out


def _finite(value: int | float) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def _operator_of(payload: bytes) -> str | None:
    with contextlib.suppress(Exception):
        op = payload_json.load_object(payload, MAX_PAYLOAD).get("operator")
        if isinstance(op, str) and op.strip():
            return op.strip()[:64]
    return None


MUTE_DESK = DeskRules(MuteRefused, "malformed mute request", "mute_refused", "mute",
                      MUTE_ANSWER_SCHEMA, _operator_of)


class MuteDesk(SignedRequestDesk):
    """The bus's side of muting (``monitor.wire.request_desk``): verified requests wait here
    for the pipeline (``poll``), their queries until it has judged them (``answer``) or
    ``answer_s`` passed; requests refused here are answered at once and alerted
    (``drain_alerts``). Thread-safe. Its answers are the plain ones (``DeskRules``)."""

    def __init__(self, gate: MuteGate, answer_s: float = 2.0) -> None:
        super().__init__(gate, MUTE_DESK, answer_s)

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
