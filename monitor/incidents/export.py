"""Exports of the index: CSV and JSON rows, and a zip with every incident's record and clips."""

from __future__ import annotations

import csv
import io
import json
import zipfile
from collections.abc import Sequence
from pathlib import Path

from monitor.incidents.store import RECORD, ROW_COLUMNS, Incident


def to_csv(incidents: Sequence[Incident]) -> str:
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=list(ROW_COLUMNS), lineterminator="\n")
    writer.writeheader()
    for incident in incidents:
        writer.writerow(incident.row())
    return out.getvalue()


def to_json(incidents: Sequence[Incident], records: bool = True) -> str:
    """Rows (with each full record: events, commands, clips, hashes, when ``records``)."""
    rows = [{**i.row(), **({"record": i.record} if records else {})} for i in incidents]
    return json.dumps(rows, indent=1) + "\n"


def to_zip(incidents: Sequence[Incident], path: Path) -> int:
    """``incidents.csv``, ``incidents.json`` and ``<id>/incident.json`` + ``<id>/<cam>.mp4``;
    the number of clips written. Written beside the target, then renamed into place."""
    tmp = path.with_name(path.name + ".part")
    clips = 0
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("incidents.csv", to_csv(incidents))
        z.writestr("incidents.json", to_json(incidents))
        for incident in incidents:
            z.writestr(f"{incident.id}/{RECORD}", json.dumps(incident.record, indent=1))
            for clip in incident.clip_paths().values():
                # an MP4 does not compress further: stored as it is
                z.write(clip, f"{incident.id}/{clip.name}", compress_type=zipfile.ZIP_STORED)
                clips += 1
    tmp.replace(path)
    return clips
