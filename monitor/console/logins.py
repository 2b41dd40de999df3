"""Password guessing against the console: counted per operator name and per client address,
with a lock-out of bounded time.

``user_failures`` wrong passwords for one name, or ``client_failures`` from one address, within
``window_s`` lock that name (or address) out for ``lockout_s``: every attempt, even with the
right password, is refused with the seconds left, and the console raises one alert per
lock-out. Why both: guesses from one address at many names lock the address; guesses from
many addresses at one name lock the name. The price: someone who reaches the port can lock an
operator out of *editing* for ``lockout_s`` at a time; editing zones is no safety function and
refusing it fails safe, while a guessed password would let the zone file change.

Pure and thread-safe; time comes from ``clock`` (monotonic seconds). Memory is bounded
(``max_tracked`` names and addresses; the oldest unlocked go first).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field

NAME_KEY_CHARS = 64  # a longer name is no operator's; counted by its first characters


@dataclass(frozen=True)
class LoginLimits:
    user_failures: int = 5
    client_failures: int = 10
    window_s: float = 300.0
    lockout_s: float = 300.0
    max_tracked: int = 4096


@dataclass(frozen=True)
class Lockout:
    """A lock-out in force: ``who`` is ``"operator 'anna'"`` or ``"client 10.0.0.5"``."""

    who: str
    seconds_left: float
    failures: int
    window_s: float

    def message(self) -> str:
        return (f"{self.who} is locked out for {self.seconds_left:.0f} s more after "
                f"{self.failures} wrong passwords within {self.window_s:.0f} s; even the right "
                "password is refused until then")


@dataclass
class _Tally:
    failures: deque[float] = field(default_factory=deque)
    locked_until: float = float("-inf")


class LoginGuard:
    """See the module's docstring."""

    def __init__(self, limits: LoginLimits | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.limits = limits or LoginLimits()
        self.clock = clock
        self._tallies: OrderedDict[tuple[str, str], _Tally] = OrderedDict()
        self._lock = threading.Lock()

    def _keys(self, client: str, name: str) -> list[tuple[tuple[str, str], int, str]]:
        lim = self.limits
        short = name[:NAME_KEY_CHARS]
        return [(("user", short), lim.user_failures, f"operator {short!r}"),
                (("client", client), lim.client_failures, f"client {client}")]

    def locked(self, client: str, name: str) -> Lockout | None:
        """The lock-out in force for this name or this address, if any."""
        now = self.clock()
        with self._lock:
            for key, limit, who in self._keys(client, name):
                tally = self._tallies.get(key)
                if tally is not None and tally.locked_until > now:
                    return Lockout(who, tally.locked_until - now, limit, self.limits.window_s)
        return None

    def failed(self, client: str, name: str) -> list[Lockout]:
        """Count a wrong password; the lock-outs it starts (for the alert)."""
        now = self.clock()
        started = []
        with self._lock:
            for key, limit, who in self._keys(client, name):
                tally = self._tally(key)
                while tally.failures and tally.failures[0] <= now - self.limits.window_s:
                    tally.failures.popleft()
                tally.failures.append(now)
                if len(tally.failures) >= limit and tally.locked_until <= now:
                    tally.locked_until = now + self.limits.lockout_s
                    tally.failures.clear()
                    started.append(Lockout(who, self.limits.lockout_s, limit,
                                           self.limits.window_s))
        return started

    def succeeded(self, client: str, name: str) -> None:
        """A right password (not locked out): this name's and address's failures are forgiven."""
        with self._lock:
            for key, _, _ in self._keys(client, name):
                tally = self._tallies.get(key)
                if tally is not None and tally.locked_until <= self.clock():
                    del self._tallies[key]

    def _tally(self, key: tuple[str, str]) -> _Tally:
        tally = self._tallies.get(key)
        if tally is not None:
            self._tallies.move_to_end(key)
            return tally
        if len(self._tallies) >= self.limits.max_tracked:
            now = self.clock()
            # a flood of new names or addresses must not push a lock-out out of memory
            victim = next((k for k, t in self._tallies.items() if t.locked_until <= now),
                          next(iter(self._tallies)))
            del self._tallies[victim]
        tally = self._tallies[key] = _Tally()
        return tally
