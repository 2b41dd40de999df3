"""The bus's side of operators' acceptances of objects since commissioning on
``<prefix>safety/objects/accept`` (``monitor.wire.object_accepts``; docs/occlusion.md).

As for mutes (``monitor.cases.mute_requests.MuteDesk``): a request the gate refuses is answered
at once and alerted (``drain_alerts``); a verified one waits for the pipeline (``poll``), its
query until the pipeline's judgement is the answer (``answer``) or ``answer_s`` has passed
without the pipeline taking it (``expire``: then it is dropped, never judged later: an
operator told "not judged" must not find the object accepted). Answers are signed with the
monitor's key and name the request they answer (``monitor.wire.answers``), so ``monitor
objects accept --monitor-key`` believes no other responder. Thread-safe.
"""

from __future__ import annotations

import collections
import contextlib
import json
import threading

from monitor.types import Alert
from monitor.wire.answers import answer_attachment, request_digest
from monitor.wire.object_accepts import (
    ACCEPT_ANSWER_SCHEMA,
    AcceptGate,
    AcceptOutcome,
    AcceptRefused,
    ObjectAccept,
    operator_of,
)
from monitor.wire.signing import Signer


class AcceptDesk:
    """Verified acceptances for the pipeline, and the queries waiting for their answer."""

    def __init__(self, gate: AcceptGate, answer_s: float = 2.0, signer: Signer | None = None,
                 who: dict | None = None) -> None:
        self.gate = gate
        self.answer_s = answer_s
        self.signer = signer
        self.who = who if who is not None else {}  # instance, boot: in every answer
        self._lock = threading.Lock()
        self._queue: collections.deque[ObjectAccept] = collections.deque(maxlen=16)
        # request id -> (query, deadline, the request's digest)
        self._pending: dict[str, tuple[object, float, str]] = {}
        self._taken: set[str] = set()  # handed to the pipeline, its judgement to come
        self._alerts: collections.deque[Alert] = collections.deque(maxlen=16)
        self.refused = 0
        self.accepted = 0

    def take(self, payload: bytes, signature: bytes | None, query, now: float,
             boot: str | None) -> None:
        """One request from the bus (``query``: the Zenoh query to answer, or None)."""
        try:
            with self._lock:
                req = self.gate.check(payload, signature, now, boot=boot)
        except Exception as exc:  # nothing a sender does may kill the callback
            reason = str(exc) if isinstance(exc, AcceptRefused) \
                else "malformed object acceptance"
            operator = operator_of(payload)
            with self._lock:
                self.refused += 1
                self._alerts.append(Alert(
                    "object_accept_refused", "warning", f"object acceptance in the name of "
                    f"{operator or '?'} refused by the bus: {reason}", "bus", now,
                    details={"operator": operator, "stage": "bus"}))
            self._reply(query, {"accepted": False, "stage": "bus", "reason": reason,
                                "operator": operator}, request_digest(payload))
            return
        with self._lock:
            self._queue.append(req)
            if query is not None:
                self._pending[req.request_id] = (query, now + self.answer_s,
                                                 request_digest(payload))

    def poll(self) -> tuple[ObjectAccept, ...]:
        """Verified requests since the last call (oldest first), for the pipeline."""
        with self._lock:
            out = tuple(self._queue)
            self._queue.clear()
            self._taken.update(r.request_id for r in out if r.request_id in self._pending)
        return out

    def answer(self, outcome: AcceptOutcome) -> None:
        """The pipeline's judgement is the answer to that request's query."""
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
                            "camera": outcome.request.camera, "zone": outcome.request.zone,
                            "objects": list(outcome.objects)}, digest)

    def expire(self, now: float) -> None:
        """Answer queries the pipeline has not taken within ``answer_s`` and drop their
        requests: what was answered "not judged" is never judged later."""
        with self._lock:
            late = [rid for rid, (_, deadline, _) in self._pending.items()
                    if now > deadline and rid not in self._taken]
            gone = [(rid, self._pending.pop(rid)) for rid in late]
            if late:
                kept = [r for r in self._queue if r.request_id not in set(late)]
                self._queue.clear()
                self._queue.extend(kept)
        for rid, (query, _, digest) in gone:
            self._reply(query, {"accepted": False, "stage": "bus", "request_id": rid,
                                "reason": "the monitor did not judge this request in time "
                                "(pipeline stalled?)"}, digest)

    def answer_all(self, why: str) -> None:
        with self._lock:
            pending = list(self._pending.items())
            self._pending.clear()
            self._taken.clear()
        for rid, (query, _, digest) in pending:
            self._reply(query, {"accepted": False, "stage": "bus", "request_id": rid,
                                "reason": why}, digest)

    @property
    def waiting(self) -> int:
        with self._lock:
            return len(self._pending)

    def drain_alerts(self) -> list[Alert]:
        with self._lock:
            out = list(self._alerts)
            self._alerts.clear()
        return out

    def _reply(self, query, body: dict, digest: str) -> None:
        """Answer a query, signed, and finalise it (the querier's get returns at once)."""
        if query is None:
            return
        key = self.gate.key_expr
        answer = json.dumps({"schema": ACCEPT_ANSWER_SCHEMA, **body, **self.who,
                             "request": digest}).encode()
        with contextlib.suppress(Exception):
            query.reply(key, answer, encoding="application/json",
                        attachment=answer_attachment(self.signer, key, answer))
        with contextlib.suppress(Exception):
            query.drop()
