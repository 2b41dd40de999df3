"""Password guessing against the console: throttled per account and per source, with delays
that grow, never a hard lock-out.

Each wrong password is counted twice, for a ``window_s``: against the name tried (the account)
and against the source it came from (its address, ``sources.source_key``). Past a free allowance
(``user_free`` wrong passwords at one name, ``client_free`` from one source) the next attempt
must wait ``first_delay_s``, doubling with each further wrong password up to ``max_delay_s``;
an attempt before then is answered 429 with the seconds left, without a password check, and
counts nothing. The first delay of a name or a source raises one alert.

Why this shape (issue 48, OWASP ASVS V2: a throttle that cannot be used to deny service):

* **No other login clears a count.** A right password forgives only the wrong passwords of that
  same name from that same source (the user's own typos): an attacker's own account, logged into
  between guesses at someone else's, clears nothing (it once cleared its address's count).
* **An account under attack can still be logged into from a clean source.** The account's
  delay holds only for sources that have failed within the window (at any name): a guesser's
  every source is one, the operator at their own desk is not. The price: each fresh source
  gets one guess at a throttled account before its delay holds it too; loopback is one source,
  an IPv6 host one /64. A source's own delay holds for every name (someone guessing from it).
* **Delays, not a lock.** The old lock-out (5 wrong passwords: even the right one refused for
  300 s, renewable for ever) let anyone who reached the port keep a named user from viewing;
  now the delay is at most ``max_delay_s`` and holds that user only at sources that failed.
* **Bounded memory that never forgets the worst.** At most ``max_tracked`` names and sources;
  a full table lets go of its least-failed eighth (expired ones first, then the fewest failures
  in the window, the oldest of those): a flood of cheap new names or sources churns among
  themselves and never resets the count of the name under attack.

Pure and thread-safe; time comes from ``clock`` (monotonic seconds).
"""

from __future__ import annotations

import heapq
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field

NAME_KEY_CHARS = 64  # a longer name is no operator's; counted by its first characters
MAX_KEPT_FAILURES = 256  # per name or source: far past the longest delay
EVICT_SHARE = 8  # a full table lets go of its least-failed eighth at once


@dataclass(frozen=True)
class LoginLimits:
    user_free: int = 3  # wrong passwords at one name before its delays start
    client_free: int = 5  # wrong passwords from one source before its delays start
    first_delay_s: float = 1.0
    max_delay_s: float = 60.0
    window_s: float = 900.0  # a wrong password counts this long
    max_tracked: int = 4096

    def delay(self, failures: int, free: int) -> float:
        if failures < free:
            return 0.0
        return min(self.max_delay_s, self.first_delay_s * 2.0 ** min(failures - free, 60))


@dataclass(frozen=True)
class Throttle:
    """A delay in force: ``who`` is ``"operator 'anna'"`` or ``"client 10.0.0.5"``."""

    who: str
    seconds_left: float
    failures: int
    window_s: float
    started: bool = False  # this wrong password began the delays of ``who`` (one alert)

    def message(self) -> str:
        return (f"{self.who}: {self.failures} wrong passwords within {self.window_s:.0f} s: "
                f"the next try is accepted in {max(1.0, self.seconds_left):.0f} s")


@dataclass
class _Tally:
    # (monotonic time, the other side: the source of a name's failure, the name of a source's)
    failures: deque[tuple[float, str]] = field(
        default_factory=lambda: deque(maxlen=MAX_KEPT_FAILURES))

    def prune(self, since: float) -> int:
        while self.failures and self.failures[0][0] <= since:
            self.failures.popleft()
        return len(self.failures)

    @property
    def last(self) -> float:
        return self.failures[-1][0] if self.failures else float("-inf")


class LoginGuard:
    """See the module's docstring."""

    def __init__(self, limits: LoginLimits | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.limits = limits or LoginLimits()
        self.clock = clock
        self._tallies: OrderedDict[tuple[str, str], _Tally] = OrderedDict()
        self._lock = threading.Lock()

    @staticmethod
    def _user(name: str) -> tuple[str, str]:
        return ("user", name[:NAME_KEY_CHARS])

    @staticmethod
    def _client(source: str) -> tuple[str, str]:
        return ("client", source)

    def _count(self, key: tuple[str, str], now: float) -> tuple[_Tally | None, int]:
        tally = self._tallies.get(key)
        if tally is None:
            return None, 0
        return tally, tally.prune(now - self.limits.window_s)

    def waiting(self, source: str, name: str) -> Throttle | None:
        """The delay in force for ``name`` tried from ``source`` (a ``source_key``), if any:
        the source's own, and the name's unless ``source`` is clean (no failure in the
        window). The longer of the two."""
        lim, now = self.limits, self.clock()
        out: Throttle | None = None
        with self._lock:
            src, src_n = self._count(self._client(source), now)
            usr, usr_n = self._count(self._user(name), now)
            candidates = [(src, src_n, lim.client_free, f"client {source}")]
            if src_n:  # a clean source is not held by the name's delay
                candidates.append((usr, usr_n, lim.user_free,
                                   f"operator {name[:NAME_KEY_CHARS]!r}"))
            for tally, n, free, who in candidates:
                if tally is None or not n:
                    continue
                left = tally.last + lim.delay(n, free) - now
                if left > 0 and (out is None or left > out.seconds_left):
                    out = Throttle(who, left, n, lim.window_s)
        return out

    def failed(self, source: str, name: str) -> list[Throttle]:
        """Count a wrong password of ``name`` from ``source``; the delays it begins (for the
        alert: the first delay of that name or source)."""
        lim, now = self.limits, self.clock()
        short = name[:NAME_KEY_CHARS]
        started = []
        with self._lock:
            for key, other, free, who in (
                    (self._user(name), source, lim.user_free, f"operator {short!r}"),
                    (self._client(source), short, lim.client_free, f"client {source}")):
                tally = self._tally(key, now)
                tally.prune(now - lim.window_s)
                tally.failures.append((now, other))
                n = len(tally.failures)
                if n == free:
                    started.append(Throttle(who, lim.delay(n, free), n, lim.window_s, True))
        return started

    def succeeded(self, source: str, name: str) -> None:
        """A right password of ``name`` from ``source``: only that name's wrong passwords from
        that source are forgiven (see the module's docstring)."""
        short = name[:NAME_KEY_CHARS]
        with self._lock:
            for key, other in ((self._user(name), source), (self._client(source), short)):
                tally = self._tallies.get(key)
                if tally is None:
                    continue
                kept = [f for f in tally.failures if f[1] != other]
                tally.failures.clear()
                tally.failures.extend(kept)
                if not kept:
                    del self._tallies[key]

    def failures(self, source: str | None = None, name: str | None = None) -> int:
        """The wrong passwords counted now against ``source`` or ``name`` (for the tests and
        the benchmark)."""
        key = self._client(source) if source is not None else self._user(name or "")
        with self._lock:
            return self._count(key, self.clock())[1]

    def __len__(self) -> int:
        return len(self._tallies)

    def _tally(self, key: tuple[str, str], now: float) -> _Tally:
        tally = self._tallies.get(key)
        if tally is not None:
            self._tallies.move_to_end(key)
            return tally
        if len(self._tallies) >= self.limits.max_tracked:
            since = now - self.limits.window_s
            # the least-failed go (ties: the longest quiet): a flood of new names or sources
            # pushes out only its own kind, never the count of the name under attack. An
            # eighth at once: one scan per 512 new entries, not one per entry
            victims = heapq.nsmallest(max(1, len(self._tallies) // EVICT_SHARE),
                                      self._tallies.items(),
                                      key=lambda item: (item[1].prune(since), item[1].last))
            for key_, _ in victims:
                del self._tallies[key_]
        tally = self._tallies[key] = _Tally()
        return tally
