"""Alert rate limiting and the alert wire format.

An alert of a kind that was published less than ``min_interval`` seconds ago is held back and
counted; the next alert of that kind that goes out carries ``repeat`` = how many were held back
since the previous one (so nothing is silently lost, and a flapping camera does not flood the bus).
Critical alerts use their own, shorter interval.

Wire format on ``<prefix>safety/alert``: a JSON object (see ``alert_to_dict``); the optional JPEG
snapshot travels as the sample's *attachment* (raw JPEG bytes), and ``snapshot`` in the JSON says
``{"encoding": "image/jpeg", "bytes": N, "sha256": HEX}`` so a reader knows to look there.

Signed alerts (a monitor with a signing key, issue 48): the attachment is the Ed25519 signature
of the payload (``SIGNATURE_BYTES``, as for commands) followed by the JPEG, if any; the payload
names the JPEG's sha256, so the signature covers the picture too. ``read_signed_alert`` checks
both. Why: the console listed unsigned, forged alerts beside the real ones; an alert an operator
reads (a refused reset, a mute) must be the monitor's.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from monitor.schema import NonNegative, section
from monitor.types import Alert
from monitor.wire.signing import SIGNATURE_BYTES, verify

SEVERITIES = ("info", "warning", "critical")
# the audit of muting is never held back: each start needs a signed, accepted request and a
# zone has one mute at a time, so they cannot flood the bus (docs/muting.md); nor is an
# operator's acceptance of an object since commissioning: signed, and once per object
# (docs/occlusion.md)
UNLIMITED_KINDS = frozenset({"zone_muted", "zone_unmuted", "object_accepted"})


@section("alerts")
class AlertLimits:
    """Minimum seconds between two published alerts of the same kind."""

    min_interval: NonNegative = 5.0
    critical_min_interval: NonNegative = 1.0


@dataclass
class AlertLimiter:
    """Decides per kind whether an alert goes out now; not thread-safe (callers hold a lock)."""

    limits: AlertLimits = field(default_factory=AlertLimits)
    _last_sent: dict[str, float] = field(default_factory=dict)
    _held: dict[str, int] = field(default_factory=dict)

    def admit(self, alert: Alert, now: float) -> int | None:
        """Return the repeat count to publish with (held-back alerts since the last one of this
        kind, 0 if none), or None when this alert is held back. ``now`` in seconds, monotonic."""
        interval = (self.limits.critical_min_interval if alert.severity == "critical"
                    else self.limits.min_interval)
        if alert.kind in UNLIMITED_KINDS:
            return 0
        last = self._last_sent.get(alert.kind)
        if last is not None and now - last < interval:
            self._held[alert.kind] = self._held.get(alert.kind, 0) + 1
            return None
        self._last_sent[alert.kind] = now
        return self._held.pop(alert.kind, 0)

    def held(self) -> dict[str, int]:
        """Alerts held back per kind and not yet reported."""
        return dict(self._held)


def alert_to_dict(alert: Alert, repeat: int = 0) -> dict:
    """The JSON body of an alert (without the bus envelope fields)."""
    if alert.severity not in SEVERITIES:
        raise ValueError(f"alert {alert.kind}: severity {alert.severity!r} not in {SEVERITIES}")
    out = {
        "kind": alert.kind,
        "severity": alert.severity,
        "message": alert.message,
        "source": alert.source,
        "time": alert.time,
        "repeat": repeat,
        "details": alert.details,
    }
    if alert.snapshot_jpeg:
        out["snapshot"] = {"encoding": "image/jpeg", "bytes": len(alert.snapshot_jpeg),
                           "where": "attachment",
                           "sha256": hashlib.sha256(alert.snapshot_jpeg).hexdigest()}
    return out


def signed_attachment(signature: bytes | None, jpeg: bytes | None) -> bytes | None:
    """The attachment of an alert: the signature, then the JPEG (either may be missing)."""
    if signature is None:
        return jpeg or None
    return signature + (jpeg or b"")


def read_signed_alert(payload: bytes, attachment: bytes | None, key_expr: str,
                      public_keys: tuple[Ed25519PublicKey, ...]
                      ) -> tuple[dict, bytes | None] | None:
    """(body, JPEG or None) of an alert signed by one of ``public_keys`` on ``key_expr``, or
    None: unsigned, signed by another key, a JPEG that is not the one the payload names, or
    not a JSON object."""
    if not attachment or len(attachment) < SIGNATURE_BYTES:
        return None
    signature, jpeg = attachment[:SIGNATURE_BYTES], attachment[SIGNATURE_BYTES:]
    if not any(verify(k, key_expr, payload, signature) for k in public_keys):
        return None
    try:
        body = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    if not isinstance(body, dict):
        return None
    snapshot = body.get("snapshot")
    if jpeg:
        named = snapshot.get("sha256") if isinstance(snapshot, dict) else None
        if named != hashlib.sha256(jpeg).hexdigest():
            return None  # a picture the signature does not cover
    return body, jpeg or None


def alert_from_dict(body: dict, attachment: bytes | None = None) -> Alert:
    """Inverse of ``alert_to_dict`` (the repeat count stays in ``details['repeat']``)."""
    details = dict(body.get("details") or {})
    if body.get("repeat"):
        details["repeat"] = body["repeat"]
    return Alert(
        kind=str(body["kind"]), severity=str(body["severity"]), message=str(body["message"]),
        source=str(body.get("source", "")), time=float(body.get("time", 0.0)),
        snapshot_jpeg=attachment if body.get("snapshot") else None, details=details,
    )


RESET_SOURCE = "reset"  # source of the alerts on the policy's reset decisions


def reset_alert(outcome, source: str, now: float) -> Alert:
    """Alert for a reset request the policy handled (``monitor.policy.ResetOutcome``):
    info when accepted, warning when refused (an operator believed the cell was clear)."""
    kind = "reset_accepted" if outcome.accepted else "reset_refused"
    return Alert(kind, "info" if outcome.accepted else "warning",
                 f"reset by {outcome.operator}: {outcome.message}", source, now,
                 details={"operator": outcome.operator, "request_id": outcome.request_id})


def mute_alert(outcome, now: float, when=None) -> Alert:
    """Alert for a judged mute request (``monitor.cases.muting.MuteOutcome``): ``zone_muted``
    (warning) when a mute starts, ``zone_unmuted`` when one is ended early, ``mute_refused``
    when refused. ``when``: turns the policy's times into the operator's clock."""
    req, mute = outcome.request, outcome.mute
    details = {"zone": req.zone, "operator": req.operator, "request_id": req.request_id,
               "duration_s": req.duration_s, "accepted": outcome.accepted}
    if not outcome.accepted:
        return Alert("mute_refused", "warning", f"mute of zone {req.zone} by {req.operator} "
                     f"refused: {outcome.reason}", "muting", now, details=details)
    if req.end:
        return unmute_alert(mute, now, when, f"ended early by {req.operator}")
    until = when(mute.end) if when is not None else f"{mute.end:.1f} s"
    return Alert("zone_muted", "warning", f"{outcome.reason}, until {until}", "muting", now,
                 details={**details, "start": mute.start, "end": mute.end, "as": mute.as_,
                          "speed_scale": mute.scale if mute.as_ == "warning" else None,
                          "max_s": mute.max_s})


def unmute_alert(mute, now: float, when=None, why: str = "expired") -> Alert:
    """``zone_unmuted``: the mute of a zone ended (expired, or ended early); the zone is
    checked as its kind again from this decision on."""
    return Alert("zone_unmuted", "warning", f"zone {mute.zone} (muted by {mute.operator}) "
                 f"unmuted: {why}; checked as its own kind again", "muting", now,
                 details={"zone": mute.zone, "operator": mute.operator, "why": why,
                          "request_id": mute.request_id, "start": mute.start,
                          "end": mute.end})


def pose_alert(rejection, source: str, now: float) -> Alert:
    """Alert for a rejected tool-pose sample or a silent pose stream (``monitor.pose.stream``)."""
    if rejection.reason == "silence":
        return Alert("pose_silence", "warning", rejection.message, source, now,
                     details={"reason": rejection.reason})
    return Alert("pose_rejected", "warning", f"tool pose rejected: {rejection.message}", source,
                 now, details={"reason": rejection.reason})
