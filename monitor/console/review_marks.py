"""Which incidents an operator marked reviewed: a small SQLite file the console owns.

``DIR/console-reviews.sqlite3`` beside the recorder's index (``--incidents DIR``), never a
column of the index: the index is the recorder's record of what the monitor saw (its readers
open it read-only), a review is the console's note about it. One row per incident: who marked
it and when. A mark outlives a console restart; an incident deleted by retention leaves its
mark behind (a few dozen bytes each).
Connections are opened per call with a short busy timeout, as the console's zone edits are.
"""

from __future__ import annotations

import contextlib
import sqlite3
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

FILE = "console-reviews.sqlite3"
BUSY_S = 1.0
SCHEMA = """
CREATE TABLE IF NOT EXISTS reviewed (
    id TEXT PRIMARY KEY,
    operator TEXT NOT NULL,
    at REAL NOT NULL
);
"""


@dataclass(frozen=True)
class ReviewMark:
    incident: str
    operator: str
    at: float  # Unix seconds

    def to_dict(self) -> dict:
        return {"operator": self.operator, "at": self.at}


class ReviewMarks:
    """The marks of one data dir (see the module's docstring)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    @contextlib.contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        con = sqlite3.connect(str(self.path), timeout=BUSY_S, isolation_level=None)
        try:
            con.executescript(SCHEMA)
            yield con
        finally:
            con.close()

    def mark(self, incident: str, operator: str, at: float | None = None) -> ReviewMark:
        """Mark ``incident`` reviewed by ``operator``; an incident already marked keeps its
        first mark (returned). OSError/sqlite3.Error: not written."""
        at = round(time.time() if at is None else at, 3)
        with self._connect() as con:
            con.execute("INSERT OR IGNORE INTO reviewed (id, operator, at) VALUES (?, ?, ?)",
                        (incident, operator, at))
            row = con.execute("SELECT operator, at FROM reviewed WHERE id = ?",
                              (incident,)).fetchone()
        return ReviewMark(incident, row[0], float(row[1]))

    def marks(self) -> dict[str, ReviewMark]:
        """Every mark, by incident id (empty when the file is missing or unreadable: the list
        then shows every incident as not reviewed, which asks for a review, never hides one)."""
        if not self.path.is_file():
            return {}  # nothing marked yet: reading makes no file
        try:
            with self._connect() as con:
                rows = con.execute("SELECT id, operator, at FROM reviewed").fetchall()
        except (sqlite3.Error, OSError):
            return {}
        return {r[0]: ReviewMark(r[0], r[1], float(r[2])) for r in rows}
