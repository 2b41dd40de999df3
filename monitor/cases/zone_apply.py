"""Signed zone applies on ``safety/zones/apply``: the wire format and the bus-side gate.

The running monitor swaps its zone set only when an operator asks for it with a request
signed by a key of the operators file (the same keys as resets, ``monitor keys new
--operator``) that names the hash of the zone set to apply (``monitor zones hash``). The
service then re-reads the zone file from its own configured path and applies it only when the
file's hash is the signed one (``monitor.service.zone_swap``): an operator signs what they
validated, and a file changed after that is refused, never applied in their name.

Checked here, before the loop sees it: the operator is listed and the signature matches (an
unsigned request is always refused: there is no ``allow_unsigned`` for zones), the cell, this
run of the monitor (``boot``, read from its status), the time (``wall`` within ``window_s``)
and the request id (never seen before).

Payload (UTF-8 JSON; the Ed25519 signature of ``monitor.wire.signing.signed_message(<apply key>,
payload)`` is the attachment)::

    {"schema": "workcell.safety.zones-apply/1", "cell": "cell1", "operator": "anna",
     "request_id": "anna-1732400000.123-5f3a", "zones_hash": "9c1f...", "note": "...",
     "wall": 1732400000.123, "boot": "4dee5337..."}
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass

from monitor.wire.answers import request_answer
from monitor.wire.resets import MAX_FIELD, MAX_RESET_PAYLOAD
from monitor.wire.signed_requests import (
    RequestKind,
    SignedGate,
    finite_number,
    load_request,
    new_request_id,
)

APPLY_SCHEMA = "workcell.safety.zones-apply/1"
APPLY_ANSWER_SCHEMA = "workcell.safety.zones-apply-answer/1"
_HASH = re.compile(r"^[0-9a-f]{8,128}$")


class ApplyRefused(ValueError):
    """A zone apply that is refused; the message is the one-line reason told to the sender."""


APPLY = RequestKind("zone apply", "zone applies", ApplyRefused, sep=":")


@dataclass(frozen=True)
class ApplyRequest:
    """A verified request: apply the zone set ``zones_hash`` (the file must have it)."""

    operator: str
    request_id: str
    zones_hash: str
    note: str
    received: float  # the bus's monotonic clock


def apply_payload(operator: str, zones_hash: str, *, cell: str = "", boot: str = "",
                  note: str = "", request_id: str = "", wall: float | None = None) -> bytes:
    """A zone-apply request body; ``boot``: the monitor's boot from its status."""
    wall = time.time() if wall is None else wall
    rid = request_id or new_request_id(operator, wall)
    body = {"schema": APPLY_SCHEMA, "operator": operator, "request_id": rid,
            "zones_hash": zones_hash, "note": note, "wall": wall, "boot": boot}
    if cell:
        body["cell"] = cell
    return json.dumps(body).encode()


class ApplyGate(SignedGate):
    """Checks zone-apply requests; remembers request ids (not thread-safe)."""

    kind = APPLY

    def parse(self, payload: bytes) -> dict:
        return _parse(payload)

    def check_boot(self, named: str, boot: str | None) -> None:
        """A zone apply must name a boot (its own words for another boot)."""
        if not named:
            raise ApplyRefused("zone apply names no monitor boot (read it from the monitor's "
                               "status; `monitor zones apply` does)")
        if boot is not None and named != boot:
            raise ApplyRefused(f"zone apply made for boot {named!r}, this monitor runs "
                               f"boot {boot!r} (a request from before a restart)")

    def request(self, body: dict, received: float) -> ApplyRequest:
        return ApplyRequest(body["operator"], body["request_id"], body["zones_hash"],
                            body["note"], received)


def _parse(payload: bytes) -> dict:
    body = load_request(payload, MAX_RESET_PAYLOAD, APPLY_SCHEMA, "zone apply request",
                        ApplyRefused)
    operator = body.get("operator")
    if not isinstance(operator, str) or not operator.strip() or len(operator) > MAX_FIELD:
        raise ApplyRefused("zone apply request without an operator id")
    rid = body.get("request_id")
    if not isinstance(rid, str) or not rid or len(rid) > MAX_FIELD:
        raise ApplyRefused("zone apply request without a request_id")
    zones_hash = body.get("zones_hash")
    if not isinstance(zones_hash, str) or not _HASH.match(zones_hash):
        raise ApplyRefused("zone apply request without a zone hash (`monitor zones hash`)")
    wall = body.get("wall")
    if isinstance(wall, bool) or not isinstance(wall, int | float) or not finite_number(wall):
        raise ApplyRefused("zone apply request without a valid wall time")
    note, boot, cell = body.get("note", ""), body.get("boot", ""), body.get("cell")
    if not isinstance(note, str) or len(note) > 4 * MAX_FIELD:
        raise ApplyRefused("zone apply request with a malformed note")
    if not isinstance(boot, str) or len(boot) > MAX_FIELD:
        raise ApplyRefused("zone apply request with a malformed boot")
    if cell is not None and not isinstance(cell, str):
        raise ApplyRefused("zone apply request with a malformed cell")
    return {"operator": operator.strip(), "request_id": rid, "zones_hash": zones_hash,
            "wall": float(wall), "note": note, "boot": boot, **({"cell": cell} if cell else {})}


# the answer to a signed request: one mechanism for every kind (monitor/wire/answers.py)
request_apply = request_answer
