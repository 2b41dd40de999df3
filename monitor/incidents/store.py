"""The incident index: one SQLite file beside the incidents' folders.

``data_dir/index.sqlite3`` (WAL) holds one row per incident; ``data_dir/<id>/`` holds its
``incident.json`` and ``<camera>.mp4`` clips. Writers (``IncidentStore``): the recorder's worker
thread, and the web console for zone edits (``monitor.console.edits``: one short INSERT;
SQLite's file locks serialise the two processes); readers (the CLI, the console, the Zenoh
queryable) open their own read-only connection (``IncidentIndex``), so a reader never holds up
a write for long.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import sqlite3
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

INDEX = "index.sqlite3"
RECORD = "incident.json"
SCHEMA = """
CREATE TABLE IF NOT EXISTS incidents (
    id TEXT PRIMARY KEY,
    wall REAL NOT NULL,
    time_s REAL NOT NULL,
    cell TEXT NOT NULL,
    causes TEXT NOT NULL,
    state TEXT NOT NULL,
    latched INTEGER NOT NULL,
    describe TEXT NOT NULL,
    operator TEXT,
    reset_accepted INTEGER,
    reset_message TEXT,
    zones_hash TEXT NOT NULL,
    config_hash TEXT NOT NULL,
    bytes INTEGER NOT NULL DEFAULT 0,
    complete INTEGER NOT NULL DEFAULT 0,
    record TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS incidents_wall ON incidents (wall);
"""
COLUMNS = ("id", "wall", "time_s", "cell", "causes", "state", "latched", "describe", "operator",
           "reset_accepted", "reset_message", "zones_hash", "config_hash", "bytes", "complete")
ROW_COLUMNS = (*COLUMNS, "alerts")  # an export's row: the index's columns and the alert kinds


@dataclass(frozen=True)
class Incident:
    """One row of the index, with its full record (``record``: events, commands, clips)."""

    id: str
    wall: float  # Unix time it was recorded at
    time_s: float  # the monitor's clock at the event (video time in replay)
    cell: str
    causes: tuple[str, ...]  # stop, latch, reset_accepted, reset_refused, fault, alert
    state: str
    latched: bool
    describe: str
    operator: str | None
    reset_accepted: bool | None
    reset_message: str | None
    zones_hash: str
    config_hash: str
    bytes: int
    complete: bool  # the clip window has ended and every file is written
    record: dict
    dir: Path

    def clip_paths(self) -> dict[str, Path]:
        """camera id -> clip file (only clips that exist)."""
        clips = self.record.get("clips", {})
        paths = {cam: self.dir / c["file"] for cam, c in clips.items() if c.get("file")}
        return {cam: p for cam, p in paths.items() if p.is_file()}

    @property
    def alert_kinds(self) -> tuple[str, ...]:
        """The kinds of the alerts raised at the incident's step (``zone_muted``,
        ``scene_change``, ...), in order, each once. Records written before the recorder kept
        them (``alerts``) give them from their events of that step."""
        kinds = self.record.get("alerts")
        if not isinstance(kinds, list):
            kinds = [e.get("kind") for e in self.record.get("events", [])
                     if isinstance(e, dict) and e.get("type") == "alert"
                     and e.get("frame") == self.record.get("frame")]
        return tuple(dict.fromkeys(str(k) for k in kinds if k))

    def cause_text(self) -> str:
        """The causes for a list, each alert named by its kind: ``stop,latch,alert(zone_muted)``
        (an alert row that does not say which alert looks like every other one)."""
        kinds = self.alert_kinds
        return ",".join(f"alert({','.join(kinds)})" if c == "alert" and kinds else c
                        for c in self.causes)

    def row(self) -> dict:
        """The flat row (CSV/JSON export, the queryable); ``alerts``: the alert kinds."""
        out = {k: getattr(self, k) for k in COLUMNS}
        out["causes"] = ",".join(self.causes)
        out["alerts"] = ",".join(self.alert_kinds)
        return out


def row_values(record: dict, size: int = 0, complete: bool = False) -> tuple:
    reset = record.get("reset") or {}
    return (record["id"], record["wall"], record["time_s"], record["cell"],
            ",".join(record["causes"]), record["state"], int(record["latched"]),
            record["describe"], reset.get("operator") or record.get("operator"),
            None if not reset else int(reset["accepted"]), reset.get("message"),
            record["zones_hash"], record["config_hash"], size, int(complete),
            json.dumps(record))


def _incident(row: sqlite3.Row, data_dir: Path) -> Incident:
    return Incident(
        id=row["id"], wall=row["wall"], time_s=row["time_s"], cell=row["cell"],
        causes=tuple(c for c in row["causes"].split(",") if c), state=row["state"],
        latched=bool(row["latched"]), describe=row["describe"], operator=row["operator"],
        reset_accepted=None if row["reset_accepted"] is None else bool(row["reset_accepted"]),
        reset_message=row["reset_message"], zones_hash=row["zones_hash"],
        config_hash=row["config_hash"], bytes=row["bytes"], complete=bool(row["complete"]),
        record=json.loads(row["record"]), dir=data_dir / row["id"])


class IncidentIndex:
    """Read-only view of a data dir's index (the console, the CLI, the queryable)."""

    def __init__(self, data_dir: str | Path) -> None:
        self.data_dir = Path(data_dir)

    @contextlib.contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection | None]:
        path = self.data_dir / INDEX
        if not path.is_file():
            yield None
            return
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=2.0)
        con.row_factory = sqlite3.Row
        try:
            yield con
        finally:
            con.close()

    def list(self, since: float | None = None, until: float | None = None,
             cause: str | None = None, limit: int | None = None) -> list[Incident]:
        """Incidents newest first; ``since``/``until``: Unix times; ``cause``: one cause, or the
        kind of an alert raised at the incident (``zone_muted``)."""
        sql, args = "SELECT * FROM incidents WHERE 1=1", []
        if since is not None:
            sql, args = sql + " AND wall >= ?", [*args, since]
        if until is not None:
            sql, args = sql + " AND wall <= ?", [*args, until]
        if cause:
            sql, args = sql + (" AND ((',' || causes || ',') LIKE ? OR EXISTS (SELECT 1 FROM "
                               "json_each(record, '$.alerts') WHERE value = ?))"), \
                [*args, f"%,{cause},%", cause]
        sql += " ORDER BY wall DESC, id DESC"
        if limit is not None:
            sql, args = sql + " LIMIT ?", [*args, int(limit)]
        with self._connect() as con:
            if con is None:
                return []
            return [_incident(r, self.data_dir) for r in con.execute(sql, args)]

    def get(self, incident_id: str) -> Incident | None:
        with self._connect() as con:
            if con is None:
                return None
            row = con.execute("SELECT * FROM incidents WHERE id = ?", (incident_id,)).fetchone()
            return _incident(row, self.data_dir) if row else None

    def clip_path(self, incident_id: str, camera: str | None = None) -> Path | None:
        """The incident's clip of ``camera`` (default: its first camera), None if none."""
        incident = self.get(incident_id)
        if incident is None:
            return None
        clips = incident.clip_paths()
        if camera is None:
            return next(iter(clips.values()), None)
        return clips.get(camera)


class IncidentStore:
    """The one writer (the recorder's worker thread). Every failure is an ``sqlite3.Error`` or
    ``OSError`` for the recorder to turn into "recording stopped"."""

    def __init__(self, data_dir: Path, timeout_s: float = 1.0) -> None:
        self.data_dir = data_dir
        data_dir.mkdir(parents=True, exist_ok=True)
        self.con = sqlite3.connect(str(data_dir / INDEX), timeout=timeout_s,
                                   check_same_thread=False, isolation_level=None)
        self.con.execute("PRAGMA journal_mode=WAL")
        self.con.executescript(SCHEMA)

    def put(self, record: dict, size: int = 0, complete: bool = False) -> None:
        marks = ",".join("?" * (len(COLUMNS) + 1))
        self.con.execute(f"INSERT OR REPLACE INTO incidents ({','.join(COLUMNS)}, record) "
                         f"VALUES ({marks})", row_values(record, size, complete))

    def oldest(self, before_wall: float | None = None,
               keep: Iterable[str] = ()) -> str | None:
        """The oldest complete incident (recorded before ``before_wall``), skipping those with
        any cause in ``keep``."""
        sql = "SELECT id FROM incidents WHERE complete = 1"
        args: tuple = ()
        if before_wall is not None:
            sql, args = sql + " AND wall < ?", (before_wall,)
        for cause in sorted(keep):
            sql, args = sql + " AND instr(',' || causes || ',', ?) = 0", (*args, f",{cause},")
        row = self.con.execute(sql + " ORDER BY wall, id LIMIT 1", args).fetchone()
        return row[0] if row else None

    def count(self, causes: Iterable[str]) -> int:
        """Incidents with any of ``causes``."""
        marks = [f",{c}," for c in sorted(causes)]
        if not marks:
            return 0
        sql = " OR ".join(["instr(',' || causes || ',', ?) > 0"] * len(marks))
        return int(self.con.execute(f"SELECT COUNT(*) FROM incidents WHERE {sql}", marks)
                   .fetchone()[0])

    def total_bytes(self) -> int:
        return int(self.con.execute("SELECT COALESCE(SUM(bytes), 0) FROM incidents")
                   .fetchone()[0])

    def delete(self, incident_id: str) -> None:
        """The folder first, then the row: a crash in between leaves a row without clips
        (shown as such), never clips that no row names and retention never deletes."""
        shutil.rmtree(self.data_dir / incident_id, ignore_errors=True)
        self.con.execute("DELETE FROM incidents WHERE id = ?", (incident_id,))

    def close(self) -> None:
        self.con.close()


def list_incidents(data_dir: str | Path, **filters) -> list[Incident]:
    """Incidents of ``data_dir``, newest first (filters as ``IncidentIndex.list``)."""
    return IncidentIndex(data_dir).list(**filters)


def clip_path(data_dir: str | Path, incident_id: str, camera: str | None = None) -> Path | None:
    return IncidentIndex(data_dir).clip_path(incident_id, camera)
