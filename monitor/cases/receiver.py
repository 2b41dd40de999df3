"""Zone set selections off Zenoh: ``<prefix>safety/case`` as a queryable (the answer says
whether the request was verified) and as a subscriber (a PLC adapter or robot program that
only puts). A verified request becomes a ``Selection`` for the pipeline's switch (``Pipeline.
take_case_events``); a refused one is answered with the reason and counted, and changes
nothing: one forged packet must not stop (let alone latch) the cell, and a flood of them must
not push a verified selection out of the queue.

With ``signed_answer`` (the service passes ``SafetyBus.signed_answer``) every answer is signed
by the monitor and names the request it answers, as resets' are: ``monitor case select
--monitor-key`` and the PLC adapter believe no rogue's "verified"."""

from __future__ import annotations

import collections
import contextlib
import json
import threading
import time
from collections.abc import Callable

import zenoh

from monitor.cases.requests import CaseGate, CasePolicy
from monitor.cases.sets import CasePlan, Refusal, Selection
from monitor.wire.answers import request_answer, request_digest
from monitor.wire.busconfig import BusKeys
from monitor.wire.request_desk import query_request
from monitor.wire.signing import load_operators

CASE_ANSWER_SCHEMA = "workcell.safety.case-answer/1"


def case_key(prefix: str) -> str:
    """The cell's selection key (``BusKeys.case``: one for every role of the cell)."""
    return BusKeys.of(prefix).case


class CaseReceiver:
    """Verifies selection requests as they arrive and queues the verified ones (bounded: the
    newest 64); refused ones are answered and counted only. Thread-safe ``poll``."""

    def __init__(self, session: zenoh.Session, key_expr: str, gate: CaseGate,
                 plan: CasePlan | None = None,
                 signed_answer: Callable[[str, dict, str], tuple[bytes, bytes | None]]
                 | None = None) -> None:
        self.session = session
        self.signed_answer = signed_answer  # (key, body, request digest) -> answer, signature
        self.key_expr = key_expr
        self.gate = gate
        self.plan = plan
        self._lock = threading.Lock()
        self._events: collections.deque[Selection] = collections.deque(maxlen=64)
        self._entities: list = []
        self.accepted = 0
        self.refused = 0

    @classmethod
    def for_bus(cls, session: zenoh.Session, bus_config, plan: CasePlan | None,
                signed_answer=None) -> CaseReceiver:
        key = case_key(bus_config.key_prefix)
        selectors = (load_operators(bus_config.selectors_file, "selectors file", "selector")
                     if bus_config.selectors_file else None)
        return cls(session, key, CaseGate(CasePolicy(selectors, bus_config.cell, key,
                                                     bus_config.case_window_s)), plan,
                   signed_answer)

    def __enter__(self) -> CaseReceiver:
        self._entities = [self.session.declare_queryable(self.key_expr, self._on_query),
                          self.session.declare_subscriber(self.key_expr, self._on_sample)]
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for entity in self._entities:
            with contextlib.suppress(Exception):  # the session may be closed: nothing to undo
                entity.undeclare()
        self._entities = []

    def poll(self) -> tuple[Selection, ...]:
        with self._lock:
            out = tuple(self._events)
            self._events.clear()
        return out

    def _take(self, payload: bytes, signature: bytes | None) -> dict:
        try:
            with self._lock:
                event = self.gate.judge(payload, signature, time.time())
        except Exception:  # nothing a sender does may kill this callback
            event = Refusal("malformed selection request")
        with self._lock:
            if isinstance(event, Refusal):
                self.refused += 1
                return {"accepted": False, "reason": event.reason}
            self._events.append(event)
            self.accepted += 1
        known = self.plan is None or self.plan.get(event.set_id) is not None
        reason = "verified; the switch follows the zone file's rules" if known else \
            f"unknown zone set {event.set_id!r}: the cell STOPs until a valid selection"
        return {"accepted": known, "reason": reason, "set": event.set_id, "seq": event.seq}

    def _on_query(self, query: zenoh.Query) -> None:
        payload, signature = query_request(query)
        answer = self._take(payload, signature)
        body = {"schema": CASE_ANSWER_SCHEMA, **answer}
        try:
            if self.signed_answer is None:
                query.reply(self.key_expr, json.dumps(body))
            else:
                raw, attachment = self.signed_answer(self.key_expr, body,
                                                     request_digest(payload))
                query.reply(self.key_expr, raw, encoding="application/json",
                            attachment=attachment)
        except Exception:  # the querier may be gone: the event is queued all the same
            pass
        finally:
            query.drop()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        signature = sample.attachment.to_bytes() if sample.attachment is not None else None
        self._take(sample.payload.to_bytes(), signature)


# the answer to a signed request: one mechanism for every kind (monitor/wire/answers.py)
request_case = request_answer
