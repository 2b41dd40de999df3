"""A consumer's inbox between Zenoh callbacks and its loop: bounded per kind, newest wins.

Zenoh delivers samples on its own threads as fast as peers send them; a consumer's loop may
fall behind (a flood of forged commands, each checked for its signature). An unbounded queue
then grows without end, and every message waits behind the flood. Here each kind (command,
alert, liveliness) has its own bound: when full, the *oldest* entry of that kind is dropped and
counted, so the newest command is never the one lost and a command flood cannot push a
liveliness change out. Dropping is safe for the consumer rule: only an accepted command moves
the deadline, and receive times are stamped in the callback, before any wait here.
"""

from __future__ import annotations

import collections
import itertools
import threading
from typing import Any

DEFAULT_BOUND = 256


class Inbox:
    """Thread-safe; ``put`` from any thread, ``get`` from the consumer's loop."""

    def __init__(self, bound: int = DEFAULT_BOUND) -> None:
        if bound < 1:
            raise ValueError("inbox bound must be at least 1")
        self.bound = bound
        self._queues: dict[str, collections.deque[tuple[int, Any]]] = {}
        self._order = itertools.count()
        self._ready = threading.Condition()
        self.dropped: collections.Counter[str] = collections.Counter()

    def put(self, kind: str, item: Any) -> None:
        with self._ready:
            q = self._queues.get(kind)
            if q is None:
                q = self._queues[kind] = collections.deque(maxlen=self.bound)
            if len(q) == self.bound:
                self.dropped[kind] += 1  # the deque drops its oldest entry
            q.append((next(self._order), item))
            self._ready.notify()

    def get(self, timeout: float) -> Any | None:
        """The oldest entry over all kinds, or None after ``timeout`` s without one."""
        with self._ready:
            if not self._ready.wait_for(lambda: any(self._queues.values()), timeout):
                return None
            q = min((q for q in self._queues.values() if q), key=lambda q: q[0][0])
            return q.popleft()[1]

    def __len__(self) -> int:
        with self._ready:
            return sum(len(q) for q in self._queues.values())

    def lengths(self) -> dict[str, int]:
        with self._ready:
            return {k: len(q) for k, q in self._queues.items()}
