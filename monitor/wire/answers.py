"""One way to send a signed request to the monitor and read its answer (resets, mutes, zone
applies, zone-set selections): a Zenoh query, the first well-formed reply.

Anyone who may declare a queryable on the key can answer (issue 31: a rogue responder made
``monitor reset`` print "accepted" while the monitor stayed latched). So the monitor signs its
answers with its command key (``answer_attachment``): the signature covers the answer, which
names the SHA-256 of the request it answers (``request``), over ``answer_key(key)``. With
``monitor_keys`` given, ``request_answer`` believes only answers signed by one of them that name
this request, and says which key it was (``signed_by``); the others are skipped (the wait goes
on) and each is told (``ignored``, ``ignored_text``): someone else answers on the key.

Signed so: resets (``monitor.bus.reset_desk``), mutes and acceptances of objects
(``monitor.wire.request_desk``), zone applies, zone-set selections and the status (a status
query carries no signature of its own: ``status_request`` is a fresh nonce the signed answer
names, so an answer recorded earlier is not taken for today's)."""

from __future__ import annotations

import hashlib
import json
import secrets

import zenoh
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from monitor.wire.signing import Signer, public_key_text, verify


def answer_key(key_expr: str) -> str:
    """What an answer's signature is bound to: never a key anything is published on."""
    return key_expr + "/answer"


def request_digest(payload: bytes) -> str:
    return hashlib.sha256(payload).hexdigest()


STATUS_REQUEST_SCHEMA = "workcell.safety.status-request/1"


def status_request() -> bytes:
    """A status query's payload: a nonce of its own for the monitor's signed answer to name."""
    return json.dumps({"schema": STATUS_REQUEST_SCHEMA, "nonce": secrets.token_hex(16)}
                      ).encode()


def answer_attachment(signer: Signer | None, key_expr: str, answer: bytes) -> bytes | None:
    """The monitor's signature of its answer (None: the monitor has no key)."""
    return signer.sign(answer_key(key_expr), answer) if signer is not None else None


def signed_by(monitor_keys, key_expr: str, request: bytes, answer: bytes,
              signature: bytes | None) -> str | None:
    """The ``ed25519:...`` text of the key in ``monitor_keys`` that signed this answer to
    ``request``; None when none did or the answer names another request."""
    return judge_answer(monitor_keys, key_expr, request, answer, signature)[0]


# why an answer was not believed (``request_answer``'s ``ignored``), in the user's words
UNSIGNED = "unsigned"
OTHER_REQUEST = "not naming this request"
OTHER_KEY = "not signed by --monitor-key"


def judge_answer(monitor_keys, key_expr: str, request: bytes, answer: bytes,
                 signature: bytes | None) -> tuple[str | None, str]:
    """(the key text that signed it, "") or (None, why it is not the monitor's answer)."""
    if signature is None:
        return None, UNSIGNED
    try:
        body = json.loads(answer)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None, OTHER_REQUEST
    if not isinstance(body, dict) or body.get("request") != request_digest(request):
        return None, OTHER_REQUEST  # a replayed answer of the monitor to another request
    for key in monitor_keys:
        if verify(key, answer_key(key_expr), answer, signature):
            return public_key_text(key), ""
    return None, OTHER_KEY


def ignored_text(ignored: list[str]) -> str:
    """``3 answers ignored (2 unsigned, 1 not naming this request)``: what ``request_answer``
    skipped, for the operator (someone else answers on the key)."""
    counts = {why: ignored.count(why) for why in dict.fromkeys(ignored)}
    return (f"{len(ignored)} answer{'s' if len(ignored) != 1 else ''} ignored ("
            + ", ".join(f"{n} {why}" for why, n in counts.items()) + ")")


def reply_of(reply, key_expr: str, request: bytes | None,
             monitor_keys: tuple[Ed25519PublicKey, ...] | None,
             ignored: list[str] | None) -> tuple[bytes, str | None] | None:
    """One Zenoh reply to ``request`` on ``key_expr``: (its payload, the key text that signed
    it) when it counts, None to skip it (an error reply; with ``monitor_keys``, an answer not
    signed by one of them for this request: why is appended to ``ignored``). Without
    ``monitor_keys`` (or ``request``) every answer counts, signed by nobody known."""
    if reply.ok is None:
        return None
    raw = reply.ok.payload.to_bytes()
    if monitor_keys is None or request is None:
        return raw, None
    attachment = reply.ok.attachment
    signer, why = judge_answer(monitor_keys, key_expr, request, raw,
                               attachment.to_bytes() if attachment is not None else None)
    if signer is None:  # not the monitor's answer to this request: not believed
        if ignored is not None:
            ignored.append(why)
        return None
    return raw, signer


def request_answer(session, key_expr: str, payload: bytes, signature: bytes | None,
                   timeout: float,
                   monitor_keys: tuple[Ed25519PublicKey, ...] | None = None,
                   ignored: list[str] | None = None) -> dict | None:
    """Send ``payload`` (signed by ``signature``) as a query on ``key_expr``; the monitor's
    answer ``{"accepted": bool, "reason": str, ...}`` (the first reply), None on timeout.
    ``monitor_keys``: only an answer signed by one of them for this request counts (others
    are skipped, and why each was is appended to ``ignored``; the wait goes on until the
    monitor's answer or ``timeout``); it comes back with ``signed_by`` set to that key's
    text."""
    # no consolidation: Zenoh's default would hold the monitor's answer until every queryable
    # on the key finished (one that never does would hold it until ``timeout``)
    for reply in session.get(key_expr, payload=payload, attachment=signature, timeout=timeout,
                             consolidation=zenoh.ConsolidationMode.NONE):
        counted = reply_of(reply, key_expr, payload, monitor_keys, ignored)
        if counted is None:
            continue
        raw, signer = counted
        try:
            body = json.loads(raw)
        except (ValueError, UnicodeDecodeError, RecursionError):
            continue
        if isinstance(body, dict) and isinstance(body.get("accepted"), bool):
            return {**body, **({"signed_by": signer} if signer else {})}
    return None
