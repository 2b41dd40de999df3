"""The console's view of the incident recorder: a narrow interface over its reader.

The console lists incidents (with filters) and asks for a clip's file; it reads the recorder's
index only through ``monitor.incidents.IncidentIndex`` (read-only connections, one per
request). ``RecorderIncidents`` adapts it to ``IncidentSource``: state and camera filters the
index does not know are applied here, and a clip path is served only when it is an existing
file inside the data directory (an index row or ``incident.json`` naming ``../../etc/passwd``
is never followed). Review marks (``review_marks.ReviewMarks``) are joined into each row; an
export (``export``) gathers an incident's record, clips and thumbnails under the same rule.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import zipfile
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Protocol

import cv2

from monitor.console.review import MAX_LISTED, IncidentFilters
from monitor.console.review_marks import FILE as MARKS_FILE
from monitor.console.review_marks import ReviewMark, ReviewMarks
from monitor.incidents import Incident, IncidentIndex

THUMB_WIDTH = 240  # pixels
MAX_THUMBS = 256  # thumbnails kept in memory (a page of the list and some)

__all__ = ["MAX_LISTED", "IncidentFilters", "IncidentSource", "NoIncidents",
           "RecorderIncidents", "clip_thumbnail"]


@dataclass
class ExportParts:
    """What an incident's export holds: its record, its clip files (inside the data dir),
    thumbnails, and the files the record names that could not be had (name, why)."""

    incident: str
    record: dict
    clips: list[tuple[str, Path]] = field(default_factory=list)
    thumbs: list[tuple[str, bytes]] = field(default_factory=list)
    missing: list[tuple[str, str]] = field(default_factory=list)

    def manifest(self) -> dict:
        return {"incident": self.incident,
                "files": ["incident.json", *(n for n, _ in self.clips),
                          *(n for n, _ in self.thumbs)],
                "missing": [{"file": n, "why": why} for n, why in self.missing]}

    def write_zip(self, out: IO[bytes]) -> None:
        """``incident.json``, the clips (stored: MP4 does not compress), ``thumb-CAM.jpg``,
        ``export.json`` (the files, and the missing ones with why)."""
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("incident.json", json.dumps(self.record, indent=1) + "\n")
            for name, path in self.clips:
                z.write(path, name, compress_type=zipfile.ZIP_STORED)
            for name, data in self.thumbs:
                z.writestr(name, data, compress_type=zipfile.ZIP_STORED)
            z.writestr("export.json", json.dumps(self.manifest(), indent=1) + "\n")


class IncidentSource(Protocol):
    """Where the console reads incidents from (the recorder's data dir, or none)."""

    def list(self, filters: IncidentFilters) -> list[dict]:
        """Incidents, newest first: dicts with id, started (Unix s), cause, kind, kinds,
        state, camera, zone, has_clip, cameras, describe, operator, reviewed, review."""
        ...

    def facets(self) -> dict:
        """The kinds and cameras of the newest incidents (what the page's filters offer)."""
        ...

    def mark_reviewed(self, incident_id: str, operator: str) -> ReviewMark | None:
        """Mark an incident reviewed (None: no such incident). OSError/sqlite3.Error: not
        written."""
        ...

    def export(self, incident_id: str) -> ExportParts | None:
        """What an export of the incident holds, or None: no such incident."""
        ...

    def clip_path(self, incident_id: str, camera: str | None = None) -> Path | None:
        """The incident's clip (an existing file inside the source's directory) or None."""
        ...

    def thumbnail(self, incident_id: str, camera: str | None = None) -> bytes | None:
        """A small JPEG of the clip's frame at the incident's moment, or None."""
        ...


class NoIncidents:
    """No ``--incidents`` given: an empty list, no clips."""

    def list(self, filters: IncidentFilters) -> list[dict]:
        return []

    def facets(self) -> dict:
        return {"kinds": [], "cameras": []}

    def mark_reviewed(self, incident_id: str, operator: str) -> ReviewMark | None:
        return None

    def export(self, incident_id: str) -> ExportParts | None:
        return None

    def clip_path(self, incident_id: str, camera: str | None = None) -> Path | None:
        return None

    def thumbnail(self, incident_id: str, camera: str | None = None) -> bytes | None:
        return None


class RecorderIncidents:
    """The recorder's data dir (``DIR/index.sqlite3``, written by the service's recorder).

    A missing, locked or half-written index lists nothing rather than failing the page."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory).resolve()
        self.index = IncidentIndex(self.directory)
        self.reviews = ReviewMarks(self.directory / MARKS_FILE)
        self._thumbs: OrderedDict[tuple, bytes | None] = OrderedDict()  # newest used last
        self._thumbs_lock = threading.Lock()

    def _inside(self, path: Path) -> Path | None:
        resolved = path.resolve()
        # a clip path never leads outside the data dir (a forged row, a symlink out)
        if not resolved.is_relative_to(self.directory) or not resolved.is_file():
            return None
        return resolved

    def _clips(self, incident: Incident) -> dict[str, Path]:
        out = {}
        for camera, path in incident.clip_paths().items():
            inside = self._inside(path)
            if inside is not None:
                out[camera] = inside
        return out

    def _row(self, incident: Incident, mark: ReviewMark | None) -> dict:
        clips = self._clips(incident)
        cameras = sorted(incident.record.get("clips", {})) or sorted(clips)
        kinds = incident_kinds(incident)
        return {"id": incident.id, "started": float(incident.wall),
                "cause": incident.cause_text(), "kind": ",".join(kinds), "kinds": kinds,
                "state": incident.state, "camera": ",".join(cameras), "cameras": cameras,
                "zone": ",".join(incident_zones(incident)), "has_clip": bool(clips),
                "clip_cameras": sorted(clips), "describe": incident.describe,
                "operator": incident.operator, "reset_accepted": incident.reset_accepted,
                "complete": incident.complete, "reviewed": mark is not None,
                "review": mark.to_dict() if mark is not None else None}

    def list(self, filters: IncidentFilters) -> list[dict]:
        limit = max(1, min(int(filters.limit), MAX_LISTED))
        # state, camera, kind and review are not columns the index filters on: read all that
        # match the index's filters (bounded by retention) and narrow here
        narrow = bool(filters.state or filters.camera or filters.kind
                      or filters.reviewed is not None)
        try:
            found = self.index.list(since=filters.since, until=filters.until,
                                    cause=filters.cause or None,
                                    limit=None if narrow else limit)
        except (sqlite3.Error, OSError, ValueError):
            return []
        marks = self.reviews.marks()
        rows = []
        for incident in found:
            if filters.state and incident.state != filters.state:
                continue
            if filters.camera and filters.camera not in incident.record.get("clips", {}):
                continue
            if filters.kind and filters.kind not in (*incident_kinds(incident),
                                                     *incident.causes):
                continue
            if filters.reviewed is not None and (incident.id in marks) != filters.reviewed:
                continue
            rows.append(self._row(incident, marks.get(incident.id)))
            if len(rows) >= limit:
                break
        return rows

    def facets(self) -> dict:
        try:
            found = self.index.list(limit=MAX_LISTED)
        except (sqlite3.Error, OSError, ValueError):
            found = []
        kinds = {k for i in found for k in (*incident_kinds(i), *i.causes)}
        cameras = {c for i in found for c in i.record.get("clips", {})}
        return {"kinds": sorted(kinds), "cameras": sorted(cameras)}

    def _get(self, incident_id: str) -> Incident | None:
        try:
            return self.index.get(incident_id)
        except (sqlite3.Error, OSError, ValueError):
            return None

    def mark_reviewed(self, incident_id: str, operator: str) -> ReviewMark | None:
        if self._get(incident_id) is None:
            return None
        return self.reviews.mark(incident_id, operator)

    def export(self, incident_id: str) -> ExportParts | None:
        incident = self._get(incident_id)
        if incident is None:
            return None
        parts = ExportParts(incident.id, incident.record)
        clips = incident.record.get("clips", {})
        for camera, info in (clips.items() if isinstance(clips, dict) else ()):
            name = info.get("file") if isinstance(info, dict) else None
            if not isinstance(name, str) or not name:
                parts.missing.append((f"{camera}: (no file named)", "the record names none"))
                continue
            path = (incident.dir / name).resolve()
            if not path.is_relative_to(self.directory):
                parts.missing.append((name, "outside the data directory: not exported"))
            elif not path.is_file():
                parts.missing.append((name, "not found in the incident's folder"))
            else:
                parts.clips.append((path.name, path))
                thumb = self.thumbnail(incident.id, camera)
                if thumb is not None:
                    parts.thumbs.append((f"thumb-{path.stem}.jpg", thumb))
        return parts

    def _clip(self, incident_id: str, camera: str | None):
        """(incident, camera, clip path) of the named or the first camera; None when the
        incident, its record or that clip cannot be had."""
        incident = self._get(incident_id)
        if incident is None:
            return None
        clips = self._clips(incident)
        camera = camera if camera is not None else next(iter(clips), None)
        path = clips.get(camera) if camera is not None else None
        return (incident, camera, path) if path is not None else None

    def clip_path(self, incident_id: str, camera: str | None = None) -> Path | None:
        found = self._clip(incident_id, camera)
        return found[2] if found is not None else None

    def thumbnail(self, incident_id: str, camera: str | None = None) -> bytes | None:
        found = self._clip(incident_id, camera)
        if found is None:
            return None
        incident, camera, path = found
        # the frame of the moment the incident began: the clip's frames before it
        info = incident.record.get("clips", {}).get(camera, {})
        at = info.get("frames_before", 0) if isinstance(info, dict) else 0
        key = (incident_id, camera, path.stat().st_mtime_ns)
        with self._thumbs_lock:
            if key in self._thumbs:
                self._thumbs.move_to_end(key)
                return self._thumbs[key]
        jpeg = clip_thumbnail(path, int(at) if isinstance(at, int) else 0)
        with self._thumbs_lock:
            self._thumbs[key] = jpeg
            while len(self._thumbs) > MAX_THUMBS:
                self._thumbs.popitem(last=False)
        return jpeg


def incident_kinds(incident: Incident) -> list[str]:
    """The incident's causes with ``alert`` named by its kinds: ``["stop", "latch"]``,
    ``["zone_muted"]`` (``["alert"]`` when the record does not say which)."""
    kinds = incident.alert_kinds
    out: list[str] = []
    for cause in incident.causes:
        out.extend(kinds if cause == "alert" and kinds else (cause,))
    return list(dict.fromkeys(out))


def incident_zones(incident: Incident) -> list[str]:
    """The zones the incident names: its command's reasons' zones, a zone edit's zone."""
    command = incident.record.get("command")
    reasons = command.get("reasons", []) if isinstance(command, dict) else []
    zones = [r.get("zone_id") for r in reasons if isinstance(r, dict)]
    edit = incident.record.get("zone_edit")
    if isinstance(edit, dict):
        zones.append(edit.get("zone"))
    return list(dict.fromkeys(str(z) for z in zones if z))


def clip_thumbnail(path: Path, at: int, width: int = THUMB_WIDTH) -> bytes | None:
    """Frame ``at`` of the clip (its last frame if shorter) scaled to ``width``, as JPEG;
    None when the clip cannot be decoded."""
    capture = cv2.VideoCapture(str(path))
    try:
        image = None
        for _ in range(max(0, min(at, 10_000)) + 1):  # read on: seeking H.264 is unreliable
            ok, frame = capture.read()
            if not ok:
                break
            image = frame
    finally:
        capture.release()
    if image is None:
        return None
    h, w = image.shape[:2]
    image = cv2.resize(image, (width, max(1, round(h * width / w))),
                       interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 75])
    return buf.tobytes() if ok else None
