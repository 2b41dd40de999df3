"""Commands on the cell's command key that this monitor did not send: a second monitor, or not.

The monitor listens on its own ``safety/command`` key for other senders. Only a message a
consumer would follow as this cell's monitor proves a second monitor (``duplicate_monitor``):
with a ``signing_key``, that is a well-formed command signed with this cell's monitor key, from
another ``boot``, whose signed ``wall`` is within ``wall_window_s`` of this monitor's clock (a
recording of an earlier run is a replay, not a monitor). Everything else -- unsigned, wrongly
signed, malformed, replayed -- is counted per kind and raised as one ``foreign_commands``
alert (the bus's rate limit applies), never taken as a second monitor: otherwise one forged
packet stops the cell.

Without a ``signing_key`` consumers cannot tell a forger from a monitor either, so every
well-formed command of another boot counts as a second monitor (STOP), as before.

Checking a signature costs ~0.15 ms; a flood of wrongly signed packets would take the CPU the
pipeline needs. At most ``verify_per_s`` signatures are checked per second (a token bucket);
the rest are counted as ``unchecked``. A real second monitor still shows: its liveliness token
(``SafetyBus``), and its heartbeats once the flood leaves room in the budget.
"""

from __future__ import annotations

import collections
import threading

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from monitor.types import Alert
from monitor.wire.consumer import parse_command
from monitor.wire.signing import SIGNATURE_BYTES, verify
from monitor.wire.verify_budget import VerifyBudget

KINDS = ("unsigned", "signature", "unchecked", "invalid", "replayed", "stale")


class ForeignCommands:
    """Sorts commands seen from other senders; thread-safe (Zenoh callbacks run anywhere)."""

    def __init__(self, public_key: Ed25519PublicKey | None, key_expr: str, *,
                 verify_per_s: float = 100.0, wall_window_s: float = 5.0) -> None:
        self.public_key = public_key
        self.key_expr = key_expr
        self.verify_per_s = verify_per_s
        self.wall_window_s = wall_window_s
        self._lock = threading.Lock()
        self._counts: collections.Counter[str] = collections.Counter()
        self._alerted: collections.Counter[str] = collections.Counter()
        self._budget = VerifyBudget(verify_per_s)

    def classify(self, payload: bytes, signature: bytes | None, own_boot: str, now: float,
                 wall_now: float) -> str | None:
        """The boot of a second monitor this message proves, or None (counted by kind).
        ``now``: monotonic seconds (the verification budget); ``wall_now``: Unix time."""
        kind, boot = self._sort(payload, signature, own_boot, now, wall_now)
        if kind:
            with self._lock:
                self._counts[kind] += 1
        return boot

    def _sort(self, payload: bytes, signature: bytes | None, own_boot: str, now: float,
              wall_now: float) -> tuple[str, str | None]:
        signed = self.public_key is not None
        if signed:  # cheapest checks first: a flood must cost little
            if signature is None:
                return "unsigned", None
            if len(signature) != SIGNATURE_BYTES:
                return "signature", None
            if not self._budget.take(now):
                return "unchecked", None
            if not verify(self.public_key, self.key_expr, payload, signature):
                return "signature", None
        try:
            body = parse_command(payload)
        except Exception:
            return "invalid", None
        if body["boot"] == own_boot:
            # our own session's commands only come back from a remote peer replaying them
            return ("replayed" if signed else ""), None
        if signed:
            wall = body.get("wall")
            if wall is None or abs(float(wall) - wall_now) > self.wall_window_s:
                return "stale", None
        return "", body["boot"]

    def counts(self) -> dict[str, int]:
        """Messages ignored per kind since start (status ``commands_foreign``)."""
        with self._lock:
            return dict(self._counts)

    def alert(self, source: str, now: float) -> Alert | None:
        """One alert for what arrived since the last call, or None when nothing did."""
        with self._lock:
            new = self._counts - self._alerted
            self._alerted = collections.Counter(self._counts)
            total = dict(self._counts)
        if not new:
            return None
        what = ", ".join(f"{k} {new[k]}" for k in KINDS if new.get(k))
        return Alert("foreign_commands", "warning",
                     f"{sum(new.values())} commands on {self.key_expr} not from this monitor "
                     f"({what}): ignored, not a second monitor; someone else publishes on the "
                     "command key", source, now, details={"new": dict(new), "total": total})
