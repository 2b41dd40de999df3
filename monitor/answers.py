"""One way to send a signed request to the monitor and read its answer (resets, mutes, zone
applies, zone-set selections): a Zenoh query, the first well-formed reply."""

from __future__ import annotations

import json

import zenoh


def request_answer(session, key_expr: str, payload: bytes, signature: bytes | None,
                   timeout: float) -> dict | None:
    """Send ``payload`` (signed by ``signature``) as a query on ``key_expr``; the monitor's
    answer ``{"accepted": bool, "reason": str, ...}`` (the first reply), None on timeout."""
    # no consolidation: Zenoh's default would hold the monitor's answer until every queryable
    # on the key finished (one that never does would hold it until ``timeout``)
    for reply in session.get(key_expr, payload=payload, attachment=signature, timeout=timeout,
                             consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is None:
            continue
        try:
            body = json.loads(reply.ok.payload.to_bytes())
        except (ValueError, UnicodeDecodeError):
            continue
        if isinstance(body, dict) and isinstance(body.get("accepted"), bool):
            return body
    return None
