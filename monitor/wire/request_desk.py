"""The bus's desk for signed requests the pipeline judges (mutes, acceptances of objects since
commissioning): one queue, one set of waiting queries and one take/answer flow, with what
differs between the kinds plugged in (``DeskRules``: the refusal class, the alert, the answer
schema; ``SignedRequestDesk.judged``: what the pipeline's judgement adds to the answer).

A request the gate refuses is answered at once, counted and alerted (``drain_alerts``); a
verified one waits for the pipeline (``poll``), its query until the pipeline's judgement is the
answer (``answer``) or ``answer_s`` has passed without the pipeline taking it (``expire``: then
it is answered "not judged" and dropped, never judged later: an operator told REFUSED must not
find the zone muted or the object accepted). One the pipeline has taken is answered with its
judgement, however late. Every answer is signed with the monitor's key and names the request
it answers (``monitor.wire.answers``), so ``--monitor-key`` believes no other responder on the
key. Thread-safe.

Here, below both users (``monitor.cases.mute_requests``, ``monitor.bus.accept_desk``): it needs
only the answers' wire format (``monitor.wire.answers``) and the bottom layer's ``Alert``;
the Zenoh query is whatever has ``reply`` and ``drop``.
"""

from __future__ import annotations

import collections
import contextlib
import json
import threading
from dataclasses import dataclass

from monitor.types import Alert
from monitor.wire.answers import answer_attachment, request_digest
from monitor.wire.signed_requests import operator_of
from monitor.wire.signing import Signer

NOT_JUDGED = "the monitor did not judge this request in time (pipeline stalled?)"


def query_request(query) -> tuple[bytes, bytes | None]:
    """The request a Zenoh query carries: its payload (empty when it has none) and its
    attachment, the signature (None when unsigned)."""
    payload = query.payload.to_bytes() if query.payload is not None else b""
    signature = query.attachment.to_bytes() if query.attachment is not None else None
    return payload, signature


@dataclass(frozen=True)
class DeskRules:
    """What one kind of request is called at the desk: its alerts and its answers."""

    refused: type[ValueError]  # the gate's refusal class: its message is the reason told
    malformed: str  # the reason told for anything else the gate raised
    alert: str  # the alert kind of a refusal at the bus ("mute_refused", ...)
    noun: str  # "mute", "object acceptance": "<noun> in the name of <operator> refused ..."
    schema: str  # the answers' schema
    max_payload: int  # the bound a refused payload is read with for the operator it names


class SignedRequestDesk:
    """Verified requests for the pipeline, and the queries waiting for their answer.
    ``gate``: ``check(payload, signature, received, boot=...)`` and ``key_expr``;
    subclasses say what a judgement adds to its answer (``judged``)."""

    def __init__(self, gate, rules: DeskRules, answer_s: float = 2.0,
                 signer: Signer | None = None, who: dict | None = None) -> None:
        self.gate = gate
        self.rules = rules
        self.answer_s = answer_s
        self.signer = signer
        self.who = who if who is not None else {}  # instance, boot: in every answer
        self._lock = threading.Lock()
        self._queue: collections.deque = collections.deque(maxlen=16)
        # request id -> (query, deadline, the request's digest)
        self._pending: dict[str, tuple[object, float, str]] = {}
        self._taken: set[str] = set()  # handed to the pipeline, its judgement to come
        self._alerts: collections.deque[Alert] = collections.deque(maxlen=16)
        self.refused = 0
        self.accepted = 0

    def judged(self, outcome) -> dict:
        """What the answer to a judged request says beyond accepted, reason and request id."""
        return {}

    def on_query(self, query, now: float, boot: str | None) -> None:
        """The bus's queryable callback: the request ``query`` carries."""
        payload, signature = query_request(query)
        self.take(payload, signature, query, now, boot)

    def take(self, payload: bytes, signature: bytes | None, query, now: float,
             boot: str | None) -> None:
        """One request from the bus (``query``: the Zenoh query to answer, or None)."""
        rules = self.rules
        try:
            with self._lock:
                req = self.gate.check(payload, signature, now, boot=boot)
        except Exception as exc:  # nothing a sender does may kill the callback
            reason = str(exc) if isinstance(exc, rules.refused) else rules.malformed
            operator = operator_of(payload, rules.max_payload)
            with self._lock:
                self.refused += 1
                self._alerts.append(Alert(
                    rules.alert, "warning", f"{rules.noun} in the name of {operator or '?'} "
                    f"refused by the bus: {reason}", "bus", now,
                    details={"operator": operator, "stage": "bus"}))
            self._reply(query, {"accepted": False, "stage": "bus", "reason": reason,
                                "operator": operator}, request_digest(payload))
            return
        with self._lock:
            self._queue.append(req)
            if query is not None:
                self._pending[req.request_id] = (query, now + self.answer_s,
                                                 request_digest(payload))

    @property
    def waiting(self) -> int:
        """Queries waiting for the pipeline's judgement now."""
        with self._lock:
            return len(self._pending)

    def poll(self) -> tuple:
        """Verified requests since the last call (oldest first), for the pipeline."""
        with self._lock:
            out = tuple(self._queue)
            self._queue.clear()
            self._taken.update(r.request_id for r in out if r.request_id in self._pending)
        return out

    def answer(self, outcome) -> None:
        """The pipeline's judgement (``accepted``, ``reason``, ``request``) is the answer to
        that request's query."""
        rid = outcome.request.request_id
        with self._lock:
            if outcome.accepted:
                self.accepted += 1
            else:
                self.refused += 1
            query, _, digest = self._pending.pop(rid, (None, 0.0, ""))
            self._taken.discard(rid)
        self._reply(query, {"accepted": outcome.accepted, "stage": "pipeline",
                            "reason": outcome.reason, "request_id": rid,
                            **self.judged(outcome)}, digest)

    def expire(self, now: float) -> None:
        """Answer queries the pipeline has not taken within ``answer_s``, and drop their
        requests: what was answered "not judged" is never judged later."""
        with self._lock:
            late = [rid for rid, (_, deadline, _) in self._pending.items()
                    if now > deadline and rid not in self._taken]
            gone = [(rid, self._pending.pop(rid)) for rid in late]
            if late:  # every heartbeat calls this: rebuild the queue only when it changes
                dropped = set(late)
                kept = [r for r in self._queue if r.request_id not in dropped]
                self._queue.clear()
                self._queue.extend(kept)
        for rid, (query, _, digest) in gone:
            self._reply(query, {"accepted": False, "stage": "bus", "request_id": rid,
                                "reason": NOT_JUDGED}, digest)

    def answer_all(self, why: str) -> None:
        """Answer every waiting query with ``why`` (the bus closes)."""
        with self._lock:
            pending = list(self._pending.items())
            self._pending.clear()
            self._taken.clear()
        for rid, (query, _, digest) in pending:
            self._reply(query, {"accepted": False, "stage": "bus", "request_id": rid,
                                "reason": why}, digest)

    def drain_alerts(self) -> list[Alert]:
        with self._lock:
            out = list(self._alerts)
            self._alerts.clear()
        return out

    def _reply(self, query, body: dict, digest: str) -> None:
        """Answer a query, signed, and finalise it (the querier's get then returns at once).
        Every answer (accepted, refused, not judged, the bus closing) names the request it
        answers and the monitor, and carries the monitor's signature: a rogue queryable on the
        key cannot make ``--monitor-key`` believe an "accepted" the monitor never said."""
        if query is None:
            return
        key = self.gate.key_expr
        answer = json.dumps({"schema": self.rules.schema, **body, **self.who,
                             "request": digest}).encode()
        with contextlib.suppress(Exception):
            query.reply(key, answer, encoding="application/json",
                        attachment=answer_attachment(self.signer, key, answer))
        with contextlib.suppress(Exception):
            query.drop()
