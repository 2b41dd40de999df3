"""Zone set selection requests on ``safety/case``: the signed wire format and the gate.

The robot program, the PLC (through ``monitor bridge plc``) or an operator's ``monitor case
select`` names the zone set the robot works in now. The monitor accepts a request only from a
*selector* listed in the selectors file (``[bus] selectors_file``, the operators file's format:
``<name> ed25519:<base64>`` per line), signed with that selector's key on this key, for this
cell, sent recently (``wall`` within ``window_s`` of the monitor's clock) and with a ``seq``
larger than every earlier one of that selector in this run of the monitor. Anything else is
refused with the reason (the answer to the sender, counted) and changes nothing
(``monitor.cases.sets``): a lie on the network never switches zones, and one forged packet
never stops the cell.

Payload (UTF-8 JSON; the Ed25519 signature of ``monitor.wire.signing.signed_message(<case key>,
payload)`` is the attachment)::

    {"schema": "workcell.safety.case/1", "cell": "cell1", "selector": "robot",
     "set": "station-b", "seq": 17, "wall": 1732400000.123}

A selector that repeats its selection (a heartbeat, needed with ``selector_ttl_s``) sends the
same set with a larger seq.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass

from monitor.cases.sets import Refusal, Selection
from monitor.wire import payload as payload_json
from monitor.wire.signed_requests import (
    RequestKind,
    check_cell,
    check_signer,
    check_window,
    finite_number,
    load_request,
)

CASE_SCHEMA = "workcell.safety.case/1"
MAX_CASE_PAYLOAD = 4 * 1024
MAX_FIELD = 128


class CaseRefused(ValueError):
    """A selection the monitor refuses; the message is the reason told to the sender."""


CASE = RequestKind("selection", "zone set selections", CaseRefused, signer="selector",
                   signers_option="bus.selectors_file")


def case_payload(selector: str, set_id: str, seq: int, *, cell: str = "",
                 wall: float | None = None) -> bytes:
    """A selection request body (``wall`` defaults to now)."""
    body = {"schema": CASE_SCHEMA, "selector": selector, "set": set_id, "seq": int(seq),
            "wall": time.time() if wall is None else float(wall)}
    if cell:
        body["cell"] = cell
    return json.dumps(body).encode()


@dataclass(frozen=True)
class CasePolicy:
    """Who may select and how strictly requests are checked."""

    selectors: dict | None  # name -> Ed25519PublicKey; None: no selectors file (all refused)
    cell: str
    key_expr: str  # the case key (part of what is signed)
    window_s: float = 5.0


class CaseGate:
    """Checks selection requests; remembers each selector's largest seq (not thread-safe)."""

    def __init__(self, policy: CasePolicy) -> None:
        self.policy = policy
        self._last_seq: dict[str, int] = {}

    def check(self, payload: bytes, signature: bytes | None,
              wall_now: float | None = None) -> Selection:
        """The verified Selection, or CaseRefused with the reason."""
        p = self.policy
        wall_now = time.time() if wall_now is None else wall_now
        body = _parse(payload)
        who = body["selector"]
        check_signer(CASE, p.selectors, who, p.key_expr, payload, signature)
        check_cell(CASE, body.get("cell", p.cell), p.cell, noun="selection")
        check_window(CASE, body["wall"], wall_now, p.window_s, noun="selection")
        last = self._last_seq.get(who)
        if last is not None and body["seq"] <= last:
            raise CaseRefused(f"seq {body['seq']} of {who!r} is not above its last {last} "
                              "(replayed)")
        self._last_seq[who] = body["seq"]
        return Selection(body["set"], who, body["seq"], max(0.0, wall_now - body["wall"]))

    def judge(self, payload: bytes, signature: bytes | None,
              wall_now: float | None = None) -> Selection | Refusal:
        """``check`` as an event for the switch: a Refusal instead of the exception."""
        try:
            return self.check(payload, signature, wall_now)
        except CaseRefused as exc:
            return Refusal(str(exc), _selector_of(payload) or "")


def _selector_of(payload: bytes) -> str | None:
    try:
        body = payload_json.load(payload[:MAX_CASE_PAYLOAD], MAX_CASE_PAYLOAD)
    except payload_json.PayloadError:
        return None
    who = body.get("selector") if isinstance(body, dict) else None
    return who[:MAX_FIELD] if isinstance(who, str) else None


def _parse(payload: bytes) -> dict:
    body = load_request(payload, MAX_CASE_PAYLOAD, CASE_SCHEMA, "selection request",
                        CaseRefused)
    who, set_id = body.get("selector"), body.get("set")
    if not isinstance(who, str) or not who.strip() or len(who) > MAX_FIELD:
        raise CaseRefused("selection request without a selector")
    if not isinstance(set_id, str) or not set_id or len(set_id) > MAX_FIELD:
        raise CaseRefused("selection request without a set")
    seq = body.get("seq")
    if isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq < 2**53:
        raise CaseRefused("selection request without an integer seq within 0..2**53")
    wall = body.get("wall")
    if isinstance(wall, bool) or not isinstance(wall, int | float) or not finite_number(wall):
        raise CaseRefused("selection request without a valid wall time")
    cell = body.get("cell")
    if cell is not None and not isinstance(cell, str):
        raise CaseRefused("selection request with a malformed cell")
    return {"selector": who.strip(), "set": set_id, "seq": seq, "wall": float(wall),
            **({"cell": cell} if cell else {})}
