"""Operator reset requests on ``safety/reset``: the signed wire format and the bus-side gate.

A reset releases a latched STOP, so the monitor accepts one only from an operator listed in the
operators file, signed with that operator's key (``monitor keys new --operator NAME``), for this
cell, for this run of the monitor (``boot``) and the STOP latched now (``latch``, the latch's
nonce), sent recently (``wall`` within ``window_s`` of the monitor's clock) and never seen before
(``request_id``). Everything else is refused by the bus, before the policy sees it, with a
reason; the policy then checks the latch nonce again (exact, at its own step) and still refuses a
reset while any STOP cause holds.

Why the nonce: request ids are remembered per process and the clock window is 30 s, so a signed
reset captured on the network could otherwise be sent again to a restarted monitor (or after a
new latch) within the window. The nonce of a latch is published in the status (``latch``, and
``command.latched_by.nonce``) while latched; ``monitor reset`` reads it and signs it into the
request. Nonces are an HMAC of (boot, latch serial) under a random key made at each start
(``LatchNonces``): unique per latch and per run, and unguessable, so no operator can be led to
sign a reset for a latch that has not happened yet.

Payload (UTF-8 JSON; the Ed25519 signature of ``monitor.wire.signing.signed_message(<reset key>,
payload)`` is the attachment)::

    {"schema": "workcell.safety.reset/1", "cell": "cell1", "operator": "anna",
     "request_id": "anna-1732400000.123-5f3a", "note": "...", "confirm_clear": false,
     "wall": 1732400000.123, "boot": "4dee5337...", "latch": "3-9f2c4e01a7b3d6e8"}
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import time
from dataclasses import dataclass, field

from monitor.policy import ResetRequest
from monitor.wire.answers import request_answer
from monitor.wire.signed_requests import (
    RequestIds,
    RequestKind,
    check_cell,
    check_signer,
    check_window,
    finite_number,
    load_request,
    new_request_id,
)
from monitor.wire.signing import Signer

RESET_SCHEMA = "workcell.safety.reset/1"
MAX_RESET_PAYLOAD = 8 * 1024
MAX_FIELD = 256


class ResetRefused(ValueError):
    """A reset request the bus refuses; the message is the reason told to the sender."""


RESET = RequestKind("reset", "resets", ResetRefused)


def reset_payload(operator: str, request_id: str = "", note: str = "", *, cell: str = "",
                  confirm_clear: bool = False, wall: float | None = None, boot: str = "",
                  latch: str = "") -> bytes:
    """A reset request body; ``request_id`` defaults to a fresh unique id. ``boot`` and
    ``latch``: the monitor's boot and latch nonce from its status (``latch_of_status``); a
    request without them is refused."""
    wall = time.time() if wall is None else wall
    rid = request_id or new_request_id(operator, wall)
    body = {"schema": RESET_SCHEMA, "operator": operator, "request_id": rid, "note": note,
            "confirm_clear": confirm_clear, "wall": wall}
    if cell:
        body["cell"] = cell
    if boot:
        body["boot"] = boot
    if latch:
        body["latch"] = latch
    return json.dumps(body).encode()


@dataclass(frozen=True)
class LatchNonces:
    """Latch serial -> nonce for one run of the monitor (``Pipeline.latch_nonces``). The key
    is random per start: nonces never repeat across runs and cannot be guessed ahead."""

    boot: str
    key: bytes = field(default_factory=lambda: os.urandom(16), repr=False)

    def __call__(self, serial: int) -> str:
        mac = hmac.new(self.key, f"{self.boot}/{serial}".encode(), hashlib.sha256)
        return f"{serial}-{mac.hexdigest()[:16]}"


def latch_of(command) -> str | None:
    """The nonce of the latch ``command`` (a policy Command) reports, None when not latched."""
    latched_by = getattr(command, "latched_by", None)
    return latched_by.nonce if latched_by is not None and latched_by.nonce else None


def latch_of_status(status: dict) -> tuple[str, str | None]:
    """(boot, latch nonce or None) from a ``safety/status`` answer."""
    boot = status.get("boot")
    latch = status.get("latch")
    return (boot if isinstance(boot, str) else "",
            latch if isinstance(latch, str) and latch else None)


def signed_reset(signer: Signer, key_expr: str, payload: bytes) -> bytes:
    """The attachment (signature) for a reset payload sent on ``key_expr``."""
    return signer.sign(key_expr, payload)


@dataclass(frozen=True)
class ResetPolicy:
    """Who may reset and how strictly requests are checked (from the bus config)."""

    operators: dict | None  # name -> Ed25519PublicKey; None = no operators file configured
    cell: str
    key_expr: str  # the reset key (part of what is signed)
    allow_unsigned: bool = False  # only for a closed lab setup; never in production
    window_s: float = 30.0


class ResetGate:
    """Checks reset requests; remembers request ids for replay protection (not thread-safe)."""

    def __init__(self, policy: ResetPolicy) -> None:
        self.policy = policy
        self._ids = RequestIds(policy.window_s)

    def check(self, payload: bytes, signature: bytes | None, received: float,
              wall_now: float | None = None, *, boot: str | None = None,
              latch: str | None = None) -> ResetRequest:
        """A ResetRequest (``time`` = ``received``, monotonic) or ResetRefused with the reason.
        ``boot``: this monitor's boot (a request naming another is refused); ``latch``: the
        nonce of the latch now published (None: not latched, the policy answers)."""
        p = self.policy
        wall_now = time.time() if wall_now is None else wall_now
        body = _parse(payload)
        operator = body["operator"]
        check_signer(RESET, p.operators, operator, p.key_expr, payload, signature,
                     allow_unsigned=p.allow_unsigned)
        check_cell(RESET, body.get("cell", p.cell), p.cell)
        nonce = body["latch"]
        if not nonce:
            raise ResetRefused("reset request names no latch nonce (read it from the monitor's "
                               "status while latched; `monitor reset` does)")
        if not body["boot"]:
            raise ResetRefused("reset request names no monitor boot (read it from the monitor's "
                               "status; `monitor reset` does)")
        if boot is not None and body["boot"] != boot:
            raise ResetRefused(f"stale latch nonce {nonce!r}: it was made for boot "
                               f"{body['boot']!r}, this monitor runs boot {boot!r} (a reset "
                               "from before a restart)")
        if latch is not None and nonce != latch:
            raise ResetRefused(f"stale latch nonce {nonce!r}: the STOP latched now has nonce "
                               f"{latch!r} (a reset made for an earlier latch)")
        check_window(RESET, body["wall"], wall_now, p.window_s)
        rid = body["request_id"]
        self._ids.use(RESET, rid, wall_now, body["wall"])
        return ResetRequest(operator=operator, time=received, request_id=rid,
                            note=body["note"], confirm_clear=body["confirm_clear"],
                            latch=nonce)


def _parse(payload: bytes) -> dict:
    body = load_request(payload, MAX_RESET_PAYLOAD, None, "reset request", ResetRefused)
    operator = body.get("operator")
    if not isinstance(operator, str) or not operator.strip() or len(operator) > MAX_FIELD:
        raise ResetRefused("reset request without an operator id")
    rid = body.get("request_id")
    if not isinstance(rid, str) or not rid or len(rid) > MAX_FIELD:
        raise ResetRefused("reset request without a request_id")
    wall = body.get("wall")
    if isinstance(wall, bool) or not isinstance(wall, int | float) or not finite_number(wall):
        raise ResetRefused("reset request without a valid wall time")
    note = body.get("note", "")
    confirm = body.get("confirm_clear", False)
    if not isinstance(note, str) or len(note) > 4 * MAX_FIELD or not isinstance(confirm, bool):
        raise ResetRefused("reset request with a malformed note or confirm_clear")
    cell = body.get("cell")
    if cell is not None and not isinstance(cell, str):
        raise ResetRefused("reset request with a malformed cell")
    boot, latch = body.get("boot", ""), body.get("latch", "")
    if not isinstance(latch, str) or len(latch) > MAX_FIELD:
        raise ResetRefused("reset request with a malformed latch nonce")
    if not isinstance(boot, str) or len(boot) > MAX_FIELD:
        raise ResetRefused("reset request with a malformed boot")
    return {"operator": operator.strip(), "request_id": rid, "wall": float(wall),
            "note": note, "confirm_clear": confirm, "boot": boot, "latch": latch,
            **({"cell": cell} if cell else {})}


# the answer to a signed request: one mechanism for every kind (monitor/wire/answers.py)
request_reset = request_answer
