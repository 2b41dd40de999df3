"""The bus's side of operator resets on ``<prefix>safety/reset``
(``monitor.bus.session.SafetyBus``).

A reset arrives as a query (or a put) signed by an operator key; the desk checks it with
``monitor.wire.resets.ResetGate`` bound to this boot and the latch published now. Refused requests
are answered at once and alerted (``drain_alerts``); verified ones wait for the pipeline
(``poll``), their queries until the policy's outcome is published (``answer``) or
``answer_s`` has passed (``expire``). A request the pipeline has not taken by then is dropped
with that answer: a reset answered "not decided" is never decided later (it would release a
latch its operator was told still holds). Of several waiting at one step the newest is taken;
the older ones are answered "superseded" at once. Every answer names the request it answers
(its SHA-256), the monitor's instance and boot, and is signed with the monitor's key
(``monitor.wire.answers``): ``monitor reset --monitor-key`` believes nothing else.
"""

from __future__ import annotations

import collections
import contextlib
import json
import threading
import time
from collections.abc import Callable

import zenoh

from monitor.policy import ResetRequest
from monitor.types import Alert
from monitor.wire.answers import answer_attachment, request_digest
from monitor.wire.request_desk import query_request
from monitor.wire.resets import MAX_RESET_PAYLOAD, ResetGate, ResetRefused
from monitor.wire.signed_requests import operator_of
from monitor.wire.signing import Signer

SCHEMA_VERSION = 1
# a taken request whose outcome never came (a stalled step's decision is discarded, and the
# stall latches anew) is answered this long after its deadline: never decided by then
TAKEN_GRACE_S = 10.0
RESET_ANSWER_SCHEMA = f"workcell.safety.reset-answer/{SCHEMA_VERSION}"


class ResetDesk:
    """Verified reset requests for the pipeline, and the queries waiting for their answer.

    Shares the bus's lock (``lock``): a request is checked against the latch the bus publishes
    at that moment (``latch``, called with the lock held), and the bus records the policy's
    outcome (``last_reset``) in the same critical section as the command carrying it."""

    def __init__(self, gate: ResetGate, key: str, answer_s: float,
                 clock: Callable[[], float], lock: threading.Lock,
                 signer: Signer | None = None, who: dict | None = None) -> None:
        self.gate = gate
        self.key = key
        self.signer = signer
        self.who = dict(who or {})  # instance, boot (set once the session is open): in answers
        self.answer_s = answer_s
        self._clock = clock
        self._lock = lock
        self._queue: collections.deque[ResetRequest] = collections.deque(maxlen=16)
        # request id -> (query, deadline, the request's digest)
        self.pending: dict[str, tuple[zenoh.Query | None, float, str]] = {}
        self.taken: set[str] = set()  # handed to the pipeline: its outcome answers them
        self.invalid = 0
        self.refused = 0
        self.last_reset: dict | None = None  # written with the bus's lock held
        self._alerts: collections.deque[Alert] = collections.deque(maxlen=16)

    def poll(self) -> list[ResetRequest]:
        """The newest verified reset request received since the last call (a list of one, or
        empty); older ones are answered "superseded" and never decided."""
        with self._lock:
            out = list(self._queue)
            self._queue.clear()
            if out and out[-1].request_id in self.pending:  # a query waits for its outcome
                self.taken.add(out[-1].request_id)
        for old in out[:-1]:
            self.answer(old.request_id, False, "superseded by a newer request", "bus")
        return out[-1:]

    def on_query(self, query: zenoh.Query, boot: str, latch: Callable[[], str | None]) -> None:
        payload, signature = query_request(query)
        self.take(payload, signature, query, boot, latch)

    def on_sample(self, sample: zenoh.Sample, boot: str,
                  latch: Callable[[], str | None]) -> None:
        signature = sample.attachment.to_bytes() if sample.attachment is not None else None
        self.take(sample.payload.to_bytes(), signature, None, boot, latch)

    def take(self, payload: bytes, signature: bytes | None, query: zenoh.Query | None,
             boot: str, latch: Callable[[], str | None]) -> None:
        """One request from the bus (``query``: the Zenoh query to answer, or None)."""
        now = self._clock()
        try:
            with self._lock:  # bound to this boot and the latch published now
                req = self.gate.check(payload, signature, now, boot=boot, latch=latch())
        except ResetRefused as exc:
            operator = operator_of(payload, MAX_RESET_PAYLOAD)
            with self._lock:
                self.refused += 1
                if operator is None:
                    self.invalid += 1
                self.last_reset = {"operator": operator, "accepted": False,
                                   "message": f"refused by the bus: {exc}", "wall": time.time()}
                self._alerts.append(Alert(
                    "reset_refused", "warning",
                    f"reset in the name of {operator or '?'} refused by the bus: {exc}", "bus",
                    now, details={"operator": operator, "stage": "bus"}))
            if query is not None:
                self._reply(query, payload, {"accepted": False, "stage": "bus",
                                             "reason": str(exc), "operator": operator})
            return
        except Exception:  # nothing a sender does may kill this callback
            with self._lock:
                self.invalid += 1
            if query is not None:
                self._reply(query, payload, {"accepted": False, "stage": "bus",
                                             "reason": "malformed reset request"})
            return
        if req.confirm_clear:
            with self._lock:
                self._alerts.append(Alert(
                    "reset_confirm_clear", "warning",
                    f"{req.operator} confirms the cell is clear (looked): holds of lost persons "
                    "may be released", "bus", now,
                    details={"operator": req.operator, "request_id": req.request_id}))
        with self._lock:
            self._queue.append(req)
            if query is not None:
                self.pending[req.request_id] = (query, now + self.answer_s,
                                                request_digest(payload))

    def answer(self, request_id: str, accepted: bool, message: str, stage: str,
               state: str | None = None) -> None:
        """Answer that request's query (if it is still waiting) and finalise it."""
        with self._lock:
            query, _, digest = self.pending.pop(request_id, (None, 0.0, ""))
            self.taken.discard(request_id)
        if query is not None:
            self._reply(query, None, {"accepted": accepted, "stage": stage,
                                      "reason": message, "request_id": request_id,
                                      "state": state}, digest)

    def expire(self) -> None:
        """Answer queries the pipeline has not taken within ``answer_s`` and drop their
        requests (never decided later); a taken one waits for its outcome, up to
        ``TAKEN_GRACE_S`` more."""
        now = self._clock()
        with self._lock:
            late = [rid for rid, (_, deadline, _) in self.pending.items()
                    if now > deadline + (TAKEN_GRACE_S if rid in self.taken else 0.0)]
            if late:  # every heartbeat calls this: rebuild the queue only when it changes
                gone = set(late)
                kept = [r for r in self._queue if r.request_id not in gone]
                self._queue.clear()
                self._queue.extend(kept)
        for rid in late:
            self.answer(rid, False, "the monitor did not decide on this request in time "
                        "(the pipeline is stalled)", "bus")

    def answer_all(self, why: str) -> None:
        with self._lock:
            rids = list(self.pending)
        for rid in rids:
            self.answer(rid, False, why, "bus")

    def _reply(self, query: zenoh.Query, request: bytes | None, body: dict,
               digest: str = "") -> None:
        """Answer a reset query, signed, and finalise it (the querier's get returns at once)."""
        answer = json.dumps({"schema": RESET_ANSWER_SCHEMA, **body, **self.who,
                             "request": request_digest(request) if request is not None
                             else digest}).encode()
        with contextlib.suppress(Exception):
            query.reply(self.key, answer, encoding="application/json",
                        attachment=answer_attachment(self.signer, self.key, answer))
        with contextlib.suppress(Exception):
            query.drop()

    def drain_alerts(self) -> list[Alert]:
        """Alerts of refused resets and of confirmed-clear resets, since the last call."""
        with self._lock:
            out = list(self._alerts)
            self._alerts.clear()
        return out
