"""What the console answers and records for a saved edit (the zone editor's and the setup
page's alike): the audit line, the ``zone_edit`` incident and, for an edit that weakens
protection, a ``zone_weakened`` incident of its own and the draft it went to
(``zones_api.ZoneEditor.edit``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from monitor.console.sources import Source
from monitor.console.zones_api import Saved

WEAKENED = "zone_weakened"  # the incident cause of an edit that weakens protection
NOTE = ("the running monitor keeps its zone set until an operator applies it (monitor zones "
        "apply; its commands name the hash in force)")


def draft_note(saved: Saved) -> str:
    return (f"this edit weakens protection ({'; '.join(saved.weakens)}): saved as the draft "
            f"{saved.file}, not the zone file, so neither a restart nor anyone but an operator's "
            f"signed apply puts it in force (monitor zones apply --zones {saved.file} "
            "--operator NAME); once applied the cell's zone set is no longer the commissioned "
            "one (commission it again)")


def record_save(console: Any, saved: Saved, target: str, operator: str, source: Source,
                incident: Callable[..., str | None], **fields: Any) -> dict:
    """Audit ``saved`` (whole), make its incidents and return the answer's body."""
    entry = console.audit.record(
        zone=target, operator=operator, **source.fields(), **fields,
        result="draft" if saved.is_draft else "saved", config_hash_before=saved.before,
        config_hash=saved.cell.config_hash, file=str(saved.file),
        **({"weakens": list(saved.weakens)} if saved.is_draft else {}))
    body = {"saved": target, "config_hash": saved.cell.config_hash, "audit": entry,
            "incident": incident(entry), "warnings": list(saved.cell.warnings),
            "draft": None, "note": NOTE}
    if saved.is_draft:
        body["weakened_incident"] = incident(entry, cause=WEAKENED)
        body["draft"] = {"file": str(saved.file), "weakens": list(saved.weakens)}
        body["note"] = draft_note(saved)
    return body
