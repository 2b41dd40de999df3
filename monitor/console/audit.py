"""The console's audit trail: one JSON line per edit attempt, appended and fsynced.

Attempts by an operator whose password was accepted are written whole (and become incidents,
``edits.py``). Refused requests (no, wrong or locked-out credential, editing off) come from
whoever reaches the port: each gets at most one line of bounded size (every text field cut to
``FIELD_CHARS``), and those lines are rate-limited (a burst of ``REFUSED_BURST``, then one per
``REFUSED_EVERY_S``); a line written after a quiet spell says how many refusals were not
written (``refused_unwritten``). Why: a flood of refused requests once wrote a 92 kB incident
each and pushed the real STOP incidents out of the recorder's retention (issue 31); the audit
must keep its worth (who tried, from where, how often) without becoming the flood's disk.
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

FIELD_CHARS = 200
REFUSED_BURST = 20
REFUSED_EVERY_S = 10.0  # ~8600 lines a day at most: ~3 MB


def bounded(value: object, limit: int = FIELD_CHARS) -> object:
    """A text field cut to ``limit`` characters, saying how long it was (numbers, None and
    booleans as they are)."""
    if value is None or isinstance(value, bool | int | float):
        return value
    text = str(value)
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text)} characters)"


@dataclass
class RefusalBudget:
    """Token bucket of refused-request audit lines; ``clock``: monotonic seconds."""

    burst: float = REFUSED_BURST
    every_s: float = REFUSED_EVERY_S
    clock: Callable[[], float] = time.monotonic
    _tokens: float = field(default=-1.0, init=False)
    _at: float | None = field(default=None, init=False)
    unwritten: int = field(default=0, init=False)

    def take(self) -> int | None:
        """The count of refusals not written since the last line (write it with this line),
        or None: do not write this one."""
        now = self.clock()
        if self._at is None:
            self._tokens = self.burst
        else:
            self._tokens = min(self.burst, self._tokens + (now - self._at) / self.every_s)
        self._at = now
        if self._tokens < 1.0:
            self.unwritten += 1
            return None
        self._tokens -= 1.0
        unwritten, self.unwritten = self.unwritten, 0
        return unwritten


@dataclass
class AuditLog:
    """Every edit attempt through the console, accepted or refused, one JSON line each
    (append-only; fsynced, so an audited edit survives a crash right after it)."""

    path: Path
    refusals: RefusalBudget = field(default_factory=RefusalBudget)
    _lock: threading.Lock = field(default_factory=threading.Lock, init=False, repr=False)

    def record(self, **fields) -> dict:
        entry = {"time": round(time.time(), 3), "event": "zone_edit", **fields}
        line = json.dumps(entry, sort_keys=True) + "\n"
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o640)
        try:
            os.write(fd, line.encode())
            os.fsync(fd)
        finally:
            os.close(fd)
        return entry

    def refused(self, **fields) -> dict | None:
        """A refused request: one bounded line, if the refusal budget allows (None: not
        written, counted in the next line's ``refused_unwritten``)."""
        with self._lock:
            unwritten = self.refusals.take()
        if unwritten is None:
            return None
        entry = {k: bounded(v) for k, v in fields.items()}
        if unwritten:
            entry["refused_unwritten"] = unwritten
        return self.record(**entry)
