"""How many signatures a receiver checks per second: a token bucket.

An Ed25519 check costs ~0.1 ms; a flood of forged messages on a key must not take the CPU the
safety loop needs. Receivers of foreign commands (``monitor.bus.foreign``) and of hand-over holds
(``monitor.bus.holds``) take a token before each check and count a message as dropped when
there is none (a dropped message never releases anything: it is treated as not received).
"""

from __future__ import annotations

import threading


class VerifyBudget:
    """At most ``per_s`` checks a second, with a burst of ``per_s``. Thread-safe."""

    def __init__(self, per_s: float) -> None:
        self.per_s = per_s
        self._tokens = per_s
        self._at: float | None = None
        self._lock = threading.Lock()

    def take(self, now: float) -> bool:
        """One check allowed at ``now`` (monotonic seconds), or False when the budget is spent."""
        with self._lock:
            if self._at is not None:
                self._tokens = min(self.per_s, self._tokens + max(0.0, now - self._at) * self.per_s)
            self._at = now
            if self._tokens < 1.0:
                return False
            self._tokens -= 1.0
            return True
