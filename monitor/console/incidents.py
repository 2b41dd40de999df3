"""The console's view of the incident recorder: a narrow interface and a placeholder.

The console never writes incidents and never needs the recorder's internals: it lists them
(with filters) and asks for a clip's file. ``DirectoryIncidents`` reads a directory with an
``index.sqlite`` (table ``incidents(id, started, cause, state, camera, clip)``, ``clip``
relative to the directory): the shape the recorder is expected to write; wiring the console to
the recorder's own reader replaces only this class.
"""

from __future__ import annotations

import contextlib
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

MAX_LISTED = 500  # a page, not the whole history


@dataclass(frozen=True)
class IncidentFilters:
    """What the incident list is narrowed to (None: any). Times are Unix seconds."""

    cause: str | None = None
    state: str | None = None
    camera: str | None = None
    since: float | None = None
    until: float | None = None
    limit: int = MAX_LISTED


class IncidentSource(Protocol):
    """Where the console reads incidents from (the recorder, or the placeholder below)."""

    def list(self, filters: IncidentFilters) -> list[dict]:
        """Incidents, newest first: dicts with id, started (Unix s), cause, state, camera,
        has_clip."""
        ...

    def clip_path(self, incident_id: str) -> Path | None:
        """The incident's clip (an existing file inside the source's directory) or None."""
        ...


class NoIncidents:
    """No ``--incidents`` given: an empty list, no clips."""

    def list(self, filters: IncidentFilters) -> list[dict]:
        return []

    def clip_path(self, incident_id: str) -> Path | None:
        return None


class DirectoryIncidents:
    """Placeholder over ``DIR/index.sqlite``, opened read-only per request (the recorder may be
    writing; a missing or half-written index lists nothing rather than failing the page)."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory).resolve()

    def _rows(self, sql: str, params: tuple) -> list[tuple]:
        index = self.directory / "index.sqlite"
        if not index.is_file():
            return []
        try:
            with contextlib.closing(sqlite3.connect(f"file:{index}?mode=ro", uri=True,
                                                    timeout=1.0)) as db:
                return db.execute(sql, params).fetchall()
        except sqlite3.Error:
            return []

    def list(self, filters: IncidentFilters) -> list[dict]:
        where, params = [], []
        for column in ("cause", "state", "camera"):
            value = getattr(filters, column)
            if value:
                where.append(f"{column} = ?")
                params.append(value)
        if filters.since is not None:
            where.append("started >= ?")
            params.append(filters.since)
        if filters.until is not None:
            where.append("started <= ?")
            params.append(filters.until)
        sql = "SELECT id, started, cause, state, camera, clip FROM incidents"
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY started DESC LIMIT ?"
        params.append(max(1, min(int(filters.limit), MAX_LISTED)))
        return [{"id": str(i), "started": float(t or 0.0), "cause": str(c or ""),
                 "state": str(s or ""), "camera": str(cam or ""), "has_clip": bool(clip)}
                for i, t, c, s, cam, clip in self._rows(sql, tuple(params))]

    def clip_path(self, incident_id: str) -> Path | None:
        rows = self._rows("SELECT clip FROM incidents WHERE id = ?", (incident_id,))
        if not rows or not rows[0][0]:
            return None
        path = (self.directory / str(rows[0][0])).resolve()
        # a clip path in the index never leads outside the directory (../../etc/passwd)
        if not path.is_relative_to(self.directory) or not path.is_file():
            return None
        return path
