"""The console's view of the incident recorder: a narrow interface over its reader.

The console lists incidents (with filters) and asks for a clip's file; it reads the recorder's
index only through ``monitor.incidents.IncidentIndex`` (read-only connections, one per
request). ``RecorderIncidents`` adapts it to ``IncidentSource``: state and camera filters the
index does not know are applied here, and a clip path is served only when it is an existing
file inside the data directory (an index row or ``incident.json`` naming ``../../etc/passwd``
is never followed).
"""

from __future__ import annotations

import sqlite3
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2

from monitor.incidents import Incident, IncidentIndex

MAX_LISTED = 500  # a page, not the whole history
THUMB_WIDTH = 240  # pixels
MAX_THUMBS = 256  # thumbnails kept in memory (a page of the list and some)


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
    """Where the console reads incidents from (the recorder's data dir, or none)."""

    def list(self, filters: IncidentFilters) -> list[dict]:
        """Incidents, newest first: dicts with id, started (Unix s), cause, state, camera,
        has_clip, cameras, describe, operator."""
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

    def _row(self, incident: Incident) -> dict:
        clips = self._clips(incident)
        cameras = sorted(incident.record.get("clips", {})) or sorted(clips)
        return {"id": incident.id, "started": float(incident.wall),
                "cause": incident.cause_text(), "state": incident.state,
                "camera": ",".join(cameras), "cameras": cameras, "has_clip": bool(clips),
                "clip_cameras": sorted(clips), "describe": incident.describe,
                "operator": incident.operator, "reset_accepted": incident.reset_accepted,
                "complete": incident.complete}

    def list(self, filters: IncidentFilters) -> list[dict]:
        limit = max(1, min(int(filters.limit), MAX_LISTED))
        # state and camera are not columns the index filters on: read all that match the
        # index's filters (bounded by retention) and narrow here
        narrow = bool(filters.state or filters.camera)
        try:
            found = self.index.list(since=filters.since, until=filters.until,
                                    cause=filters.cause or None,
                                    limit=None if narrow else limit)
        except (sqlite3.Error, OSError, ValueError):
            return []
        rows = []
        for incident in found:
            if filters.state and incident.state != filters.state:
                continue
            if filters.camera and filters.camera not in incident.record.get("clips", {}):
                continue
            rows.append(self._row(incident))
            if len(rows) >= limit:
                break
        return rows

    def _clip(self, incident_id: str, camera: str | None):
        """(incident, camera, clip path) of the named or the first camera; None when the
        incident, its record or that clip cannot be had."""
        try:
            incident = self.index.get(incident_id)
        except (sqlite3.Error, OSError, ValueError):
            return None
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
