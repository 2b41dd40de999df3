"""Every zone edit through the console is an audited incident (cause ``zone_edit``).

With ``--incidents DIR`` the console records each save attempt, accepted or refused, as an
incident of the recorder's data dir: operator, zone, result (saved, invalid, refused), the
validation message, the zone-set hash of the file before and after, the client, and the
verdict the console showed at that moment. No clip.

Why the console writes the index itself: the service's recorder is another process, and SQLite
serialises writers across processes with its own file locks (WAL mode; a lock dies with its
process). One edit is one short autocommit INSERT on a connection opened and closed around it,
with a busy timeout of ``BUSY_S``: the recorder's worker (never the safety loop) waits for it at
most that long, well inside its own ``sqlite_timeout_s``. An inbox folder the recorder ingests
would hold edits back until a recorder runs and would need a second reader; the audit log
(``ZONEFILE.audit.jsonl``) stays the first record either way: an edit whose incident could not
be written (index locked, disk full) is still audited, with ``incident_error``.
"""

from __future__ import annotations

import contextlib
import json
import secrets
import sqlite3
import time
from pathlib import Path

from monitor.incidents.store import RECORD, IncidentStore

CAUSE = "zone_edit"
SCHEMA = "workcell.incident/1"
BUSY_S = 1.0


class ZoneEditIncidents:
    """Writes zone-edit incidents into a recorder data dir (see the module's docstring)."""

    def __init__(self, data_dir: str | Path, cell: str) -> None:
        self.data_dir = Path(data_dir)
        self.cell = cell

    def record(self, entry: dict, state: str = "", cause: str = CAUSE) -> str:
        """One incident for an audit ``entry``; its id. ``cause``: ``zone_edit``, or
        ``zone_weakened`` for the incident of its own of an edit that weakens protection
        (saved as a draft, in force only after a signed apply). OSError/sqlite3.Error: not
        written."""
        wall = float(entry.get("time") or time.time())
        incident_id = (time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(wall))
                       + f"-{'weak' if cause != CAUSE else 'zone'}-{secrets.token_hex(3)}")
        operator = entry.get("operator")
        result = str(entry.get("result", ""))
        before, after = entry.get("config_hash_before", ""), entry.get("config_hash", "")
        zone = entry.get("zone", "")
        if cause != CAUSE:
            text = (f"zone edit by {operator} weakens protection: "
                    f"{'; '.join(entry.get('weakens') or [])} (zone set {str(after)[:12]} kept "
                    f"as the draft {entry.get('file', '')}: in force only after an operator's "
                    "signed apply, then no longer the commissioned zone set)")
        elif result == "draft":
            text = (f"zone edit by {operator}: {zone} {entry.get('action', 'changed')} as a "
                    f"draft (zone set {str(before)[:12]} -> {str(after)[:12]}, weakens "
                    "protection: in force only after an operator's signed apply)")
        elif result == "saved":
            text = (f"zone edit by {operator}: {zone} {entry.get('action', 'changed')} "
                    f"(zone set {str(before)[:12]} -> {str(after)[:12]}, not applied to the "
                    "running monitor until an operator signs it)")
        else:
            text = (f"zone edit of {zone} by {operator or '(no credential)'} {result}: "
                    f"{entry.get('error', '')}")
        record = {
            "schema": SCHEMA, "id": incident_id, "cell": self.cell, "wall": round(wall, 3),
            "time_s": round(wall, 3), "frame": None, "causes": [cause], "state": state,
            "latched": False, "describe": text, "command": None, "faults": [], "reset": None,
            "operator": operator, "zones_hash": str(before or after or ""), "config_hash": "",
            "zone_edit": {"operator": operator, "zone": zone, "result": result,
                          "accepted": result in ("saved", "draft"),
                          "in_force_after_signed_apply": result == "draft",
                          "weakens": entry.get("weakens") or [],
                          "message": entry.get("error", ""),
                          "old_hash": before, "new_hash": after,
                          "client": entry.get("client", ""),
                          "forwarded_for": entry.get("forwarded_for"),
                          "file": entry.get("file", "")},
            "events": [], "commands": [], "clips": {}, "complete": True,
        }
        folder = self.data_dir / incident_id
        folder.mkdir(parents=True)
        (folder / RECORD).write_text(json.dumps(record, indent=1) + "\n")
        store = IncidentStore(self.data_dir, BUSY_S)
        try:
            store.put(record, (folder / RECORD).stat().st_size, complete=True)
        finally:
            with contextlib.suppress(sqlite3.Error):
                store.close()
        return incident_id
