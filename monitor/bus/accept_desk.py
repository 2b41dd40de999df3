"""The bus's side of operators' acceptances of objects since commissioning on
``<prefix>safety/objects/accept`` (``monitor.wire.object_accepts``; docs/occlusion.md).

The desk of mutes (``monitor.wire.request_desk.SignedRequestDesk``): a request the gate refuses
is answered at once and alerted (``drain_alerts``); a verified one waits for the pipeline
(``poll``), its query until the pipeline's judgement is the answer (``answer``) or ``answer_s``
has passed without the pipeline taking it (``expire``: then it is dropped, never judged later:
an operator told "not judged" must not find the object accepted). Answers are signed with the
monitor's key and name the request they answer (``monitor.wire.answers``), so ``monitor
objects accept --monitor-key`` believes no other responder. Thread-safe.
"""

from __future__ import annotations

from monitor.wire.object_accepts import (
    ACCEPT_ANSWER_SCHEMA,
    MAX_PAYLOAD,
    AcceptGate,
    AcceptOutcome,
    AcceptRefused,
)
from monitor.wire.request_desk import DeskRules, SignedRequestDesk
from monitor.wire.signing import Signer

ACCEPT_DESK = DeskRules(AcceptRefused, "malformed object acceptance", "object_accept_refused",
                        "object acceptance", ACCEPT_ANSWER_SCHEMA, MAX_PAYLOAD)


class AcceptDesk(SignedRequestDesk):
    """Verified acceptances for the pipeline, and the queries waiting for their answer."""

    def __init__(self, gate: AcceptGate, answer_s: float = 2.0, signer: Signer | None = None,
                 who: dict | None = None) -> None:
        super().__init__(gate, ACCEPT_DESK, answer_s, signer, who)

    def judged(self, outcome: AcceptOutcome) -> dict:
        """The camera and zone asked for, and the objects accepted."""
        return {"camera": outcome.request.camera, "zone": outcome.request.zone,
                "objects": list(outcome.objects)}
