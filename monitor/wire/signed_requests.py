"""What every signed request to the monitor checks the same way: who signed it, for which cell,
when, and whether it was seen before.

Resets (``monitor.wire.resets``), mutes (``monitor.cases.mute_requests``), zone applies
(``monitor.cases.zone_apply``) and zone set selections (``monitor.cases.requests``) each have their
own payload and their own rules (a latch nonce, a zone, a hash, a seq), but the first checks are one
rule, kept here so that a fix to one is a fix to all: the signer is listed and the Ed25519 signature
over (key, payload) is theirs; the request names this cell; its wall time is within the window of
the monitor's clock; its request id was not used before (replay).

Each check raises the caller's own refusal class (a ``ValueError`` whose message is the reason
told to the sender), so callers keep their exception types and the wording their users see.

What their parsers share is here too: the bounded, schema-checked JSON object
(``load_request``), the string and number fields every gate checks alike (``text_fields``,
``number_fields``), the operator a refused payload names for its alert (``operator_of``) and a
fresh request id (``new_request_id``).

``SignedGate`` runs them in one order for the requests that name an operator, a monitor boot
and a request id (mutes, acceptances of objects, zone applies): each gate says only how its
payload is read (``parse``) and what a verified one becomes (``request``).
"""

from __future__ import annotations

import collections
import contextlib
import math
import os
import time
from dataclasses import dataclass

from monitor.wire import payload as payload_json
from monitor.wire.signing import verify

# request ids remembered at most (a flood of valid requests must not grow memory without bound)
MAX_REMEMBERED = 10_000


@dataclass(frozen=True)
class RequestKind:
    """How one kind of request is named in its refusals."""

    name: str  # "reset", "mute", "zone apply", "selection"
    plural: str  # "resets", "mutes", ...
    refused: type[ValueError]  # the caller's refusal class
    signer: str = "operator"  # "operator" or "selector"
    signers_option: str = "bus.operators_file"
    sep: str = ";"  # how the "no signers" refusal joins its two halves (kept as users know it)


def new_request_id(operator: str, wall: float) -> str:
    """A request id nobody used: ``<operator>-<wall>-<random>``."""
    return f"{operator}-{wall:.3f}-{os.urandom(3).hex()}"


def load_request(payload: bytes, max_payload: int, schema: str | None, noun: str,
                 refused: type[ValueError]) -> dict:
    """The request's JSON object, at most ``max_payload`` bytes, with that ``schema`` (None:
    any JSON object); ``refused`` ("<noun> too large", ...) otherwise."""
    if len(payload) > max_payload:
        raise refused(f"{noun} too large")
    try:
        body = payload_json.load(payload, max_payload)
    except payload_json.PayloadError as exc:
        raise refused(f"{noun} refused: {exc}") from None
    if schema is None:
        if not isinstance(body, dict):
            raise refused(f"{noun} is not a JSON object")
    elif not isinstance(body, dict) or body.get("schema") != schema:
        raise refused(f"{noun} is not a {schema} object")
    return body


def text_fields(body: dict, keys: tuple[str, ...], max_field: int, noun: str,
                refused: type[ValueError]) -> dict:
    """Each of ``keys``: a non-blank string of at most ``max_field`` characters (the operator
    stripped); "<noun> without a valid <key>" otherwise."""
    out: dict = {}
    for key in keys:
        value = body.get(key)
        if not isinstance(value, str) or not value.strip() or len(value) > max_field:
            raise refused(f"{noun} without a valid {key}")
        out[key] = value.strip() if key == "operator" else value
    return out


def number_fields(body: dict, keys: tuple[str, ...], noun: str,
                  refused: type[ValueError]) -> dict:
    """Each of ``keys``: a finite JSON number (never a bool), as a float; "<noun> without a
    valid <key>" otherwise."""
    out: dict = {}
    for key in keys:
        value = body.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not finite_number(value):
            raise refused(f"{noun} without a valid {key}")
        out[key] = float(value)
    return out


def finite_number(value: int | float) -> bool:
    try:
        return math.isfinite(value)  # a JSON integer may be too large for a float
    except OverflowError:
        return False


def operator_of(payload: bytes, max_payload: int) -> str | None:
    """The operator a (possibly refused) payload names, for the refusal's alert and answer."""
    with contextlib.suppress(Exception):
        op = payload_json.load_object(payload, max_payload).get("operator")
        if isinstance(op, str) and op.strip():
            return op.strip()[:64]
    return None


def check_signer(kind: RequestKind, signers: dict | None, who: str, key_expr: str,
                 payload: bytes, signature: bytes | None, *,
                 allow_unsigned: bool = False) -> None:
    """Refuse unless ``who`` is a listed signer whose signature over (key, payload) this is.
    ``signers`` None: no file configured, everything refused (unless ``allow_unsigned``, a lab
    setting only resets have)."""
    if signers is None:
        if allow_unsigned:
            return
        raise kind.refused(f"no {kind.signer}s configured on this monitor ({kind.signers_option})"
                           f"{kind.sep} {kind.plural} are refused")
    if who not in signers:
        raise kind.refused(f"unknown {kind.signer} {who!r}")
    if signature is None:
        raise kind.refused(f"unsigned {kind.name} in the name of {who!r}")
    if not verify(signers[who], key_expr, payload, signature):
        raise kind.refused(f"signature does not match {kind.signer} {who!r}")


def check_cell(kind: RequestKind, cell: str, ours: str, noun: str = "request") -> None:
    """Refuse a request made for another cell."""
    if cell != ours:
        raise kind.refused(f"{noun} is for cell {cell!r}, this is {ours!r}")


def check_window(kind: RequestKind, wall: float, wall_now: float, window_s: float,
                 noun: str = "request") -> None:
    """Refuse a request whose wall time is outside the window of the monitor's clock: replayed
    later, or a wrong clock."""
    off = wall - wall_now
    if not abs(off) <= window_s:  # also refuses NaN
        raise kind.refused(f"{noun} time is {off:+.1f} s off the monitor's clock (allowed "
                           f"±{window_s:g} s): replayed or clock wrong")


class RequestIds:
    """Request ids seen in the last ``2 x window_s`` seconds of request time (and at most
    ``MAX_REMEMBERED``): older ones are refused by the clock window anyway -- unless the
    monitor's clock steps back (NTP) and that window comes round again. So the newest request
    time ever forgotten is kept, and a request from at or before it is refused: after a step
    back, requests are refused until the clock has passed it again (a nuisance, never a replay).
    Not thread-safe."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self._seen: collections.OrderedDict[str, float] = collections.OrderedDict()
        self.forgotten = -math.inf  # the newest request wall time no longer remembered

    def use(self, kind: RequestKind, request_id: str, wall_now: float,
            wall: float | None = None) -> None:
        """Remember ``request_id`` (sent at ``wall``, default ``wall_now``), or refuse it as
        replayed when it was used before or is not newer than what was forgotten."""
        wall = wall_now if wall is None else wall
        horizon = 2 * self.window_s
        while self._seen and (wall_now - next(iter(self._seen.values())) > horizon
                              or len(self._seen) > MAX_REMEMBERED):
            self.forgotten = max(self.forgotten, self._seen.popitem(last=False)[1])
        if request_id in self._seen:
            raise kind.refused(f"request id {request_id!r} was already used (replayed)")
        if not wall > self.forgotten:
            raise kind.refused(f"request time is {self.forgotten - wall:.1f} s before requests "
                               "this monitor no longer remembers (its clock stepped back?): "
                               "refused as a possible replay")
        self._seen[request_id] = wall


class SignedGate:
    """Checks an operator's signed request: the payload (``parse``, the gate's own), the
    signer, the cell, this boot of the monitor, the clock window and the request id, in that
    order (the first refusal is the one told); remembers request ids (not thread-safe: the
    bus's desk holds a lock). ``kind``: the gate's ``RequestKind``; a request with no ``cell``
    is for this one (zone applies may leave it out)."""

    kind: RequestKind

    def __init__(self, operators: dict | None, cell: str, key_expr: str,
                 window_s: float = 30.0) -> None:
        self.operators = operators
        self.cell = cell
        self.key_expr = key_expr
        self.window_s = window_s
        self._ids = RequestIds(window_s)

    def parse(self, payload: bytes) -> dict:
        """The checked fields: at least ``operator``, ``boot``, ``wall`` and ``request_id``;
        ``kind.refused`` with the reason otherwise."""
        raise NotImplementedError

    def request(self, body: dict, received: float):
        """What a verified request becomes (``received``: the monitor's monotonic clock)."""
        raise NotImplementedError

    def check_boot(self, named: str, boot: str | None) -> None:
        """Refuse a request made for another boot of the monitor (``boot`` None: not
        checked)."""
        if boot is not None and named != boot:
            raise self.kind.refused(f"request names monitor boot {named!r}, this monitor runs "
                                    f"boot {boot!r} (a request from before a restart?)")

    def check(self, payload: bytes, signature: bytes | None, received: float,
              wall_now: float | None = None, *, boot: str | None = None):
        """The verified request (``request``) or ``kind.refused`` with the reason."""
        kind = self.kind
        wall_now = time.time() if wall_now is None else wall_now
        body = self.parse(payload)
        check_signer(kind, self.operators, body["operator"], self.key_expr, payload, signature)
        check_cell(kind, body.get("cell", self.cell), self.cell)
        self.check_boot(body["boot"], boot)
        check_window(kind, body["wall"], wall_now, self.window_s)
        self._ids.use(kind, body["request_id"], wall_now, body["wall"])
        return self.request(body, received)
