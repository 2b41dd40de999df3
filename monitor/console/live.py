"""The console's live view: the cell's verdict, the live picture, detections and alert
snapshots, drawn.

The picture is the monitor's live preview (``monitor.bus.preview``: a small JPEG per camera at a low
rate, ``[preview] fps``, signed with the monitor's key; a preview not signed by a pinned key is
not shown), or, without one in the last ``PREVIEW_FRESH_S``, the snapshot of a recent alert of
that camera, else the camera's reference image (``--reference cam0=FILE``). Over it the console
draws the zones (the same drawing as ``monitor zones preview``), the zones hit and the person
boxes of the newest detections. The state and its reasons come from the consumer rule
(``monitor.adapters.follower``): signed by the monitor's key, STOP on silence, exactly what a
robot-side adapter would follow, never the raw message.

The Zenoh callbacks only store bytes (newest wins, bounded; a live picture is checked first:
at most ``MAX_PREVIEW_BYTES``, its signature, its JPEG magic); parsing and drawing happen when a
browser asks, at most every ``min_render_s`` per camera.
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from dataclasses import asdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from monitor.adapters.snapshot import SafetySnapshot
from monitor.bus.preview import MAX_PREVIEW_BYTES, read_preview
from monitor.types import Alert
from monitor.zones.draw import draw_zones
from monitor.zones.files import Cell

MAX_DETECTIONS_BYTES = 1_000_000  # a detections message larger than this is not drawn
SNAPSHOT_FRESH_S = 30.0  # an alert snapshot older than this gives way to the reference image
DETECTIONS_FRESH_S = 2.0  # older detections are not drawn as current
PREVIEW_FRESH_S = 5.0  # an older live picture gives way to the alert snapshot / reference
MAX_PREVIEW_CAMERAS = 64  # pictures of more cameras than this are not kept


class LiveState:
    """The newest of everything the live page shows; an ``Output`` of the follower."""

    name = "console"

    def __init__(self, clock=time.monotonic, preview_keys: tuple = (),
                 require_signed: bool = True, preview_key: str = "") -> None:
        self.clock = clock
        self._lock = threading.Lock()
        self.snapshot: SafetySnapshot | None = None
        self.detections: dict[str, tuple[bytes, float]] = {}  # camera -> (payload, received)
        self.alert_images: dict[str, tuple[bytes, float]] = {}  # camera -> (jpeg, received)
        self.alerts: deque[dict] = deque(maxlen=50)
        # live pictures: checked against the monitor's keys (--monitor-key) unless the console
        # runs --unauthenticated
        self.preview_keys, self.require_signed = tuple(preview_keys), require_signed
        self.preview_key = preview_key
        self.previews: dict[str, tuple[bytes, float]] = {}  # camera -> (payload, received)
        self.previews_refused = 0

    # --- writers (follower thread, Zenoh callbacks) ---------------------------------------
    def publish(self, snapshot: SafetySnapshot) -> None:
        with self._lock:
            self.snapshot = snapshot

    def close(self) -> None:
        pass

    def on_detections(self, payload: bytes) -> None:
        if len(payload) > MAX_DETECTIONS_BYTES:
            return
        camera = _camera_of(payload)
        if camera is not None:
            with self._lock:
                self.detections[camera] = (payload, self.clock())

    def on_alert(self, payload: bytes, attachment: bytes | None) -> None:
        body = _json(payload)
        if body is None:
            return
        entry = {k: body.get(k) for k in ("kind", "severity", "message", "source", "wall")}
        entry["received"] = time.time()
        with self._lock:
            self.alerts.appendleft(entry)
            if attachment and attachment[:2] == b"\xff\xd8":  # a JPEG, by its magic
                self.alert_images[str(body.get("source", ""))] = (attachment, self.clock())

    def on_preview(self, payload: bytes, attachment: bytes | None) -> None:
        """A live picture: kept (newest per camera) only when it is a signed preview."""
        preview = read_preview(payload, attachment, self.preview_key, self.preview_keys,
                               self.require_signed) if len(payload) <= MAX_PREVIEW_BYTES \
            else None
        with self._lock:
            if preview is None or (preview.camera not in self.previews
                                   and len(self.previews) >= MAX_PREVIEW_CAMERAS):
                self.previews_refused += 1
                return
            self.previews[preview.camera] = (preview.jpeg, self.clock())

    def add_alert(self, alert: Alert) -> None:
        """One of the console's own alerts (a login lock-out), shown with the monitor's."""
        entry = {"kind": alert.kind, "severity": alert.severity, "message": alert.message,
                 "source": alert.source, "wall": alert.time, "received": time.time()}
        with self._lock:
            self.alerts.appendleft(entry)

    # --- readers (web requests) ------------------------------------------------------------
    def state(self) -> dict:
        with self._lock:
            snap = self.snapshot
            alerts = list(self.alerts)[:10]
            seen = {cam: self.clock() - t for cam, (_, t) in self.detections.items()}
            pictures = {cam: self.clock() - t for cam, (_, t) in self.previews.items()}
            refused = self.previews_refused
        body: dict[str, Any] = {"state": "STOP", "reason": "console starting", "alerts": alerts,
                                "detections_age_s": {c: round(a, 2) for c, a in seen.items()},
                                "preview_age_s": {c: round(a, 2) for c, a in pictures.items()},
                                "previews_refused": refused}
        if snap is not None:
            body.update(asdict(snap))
        return body

    def latest_detections(self, camera: str) -> tuple[dict | None, float | None]:
        with self._lock:
            item = self.detections.get(camera)
        if item is None:
            return None, None
        return _json(item[0]), self.clock() - item[1]

    def preview(self, camera: str) -> tuple[bytes | None, float | None]:
        """The newest live picture of ``camera`` and its age (s), or (None, None)."""
        with self._lock:
            item = self.previews.get(camera)
        return (item[0], self.clock() - item[1]) if item else (None, None)

    def alert_image(self, camera: str) -> tuple[bytes | None, float | None]:
        with self._lock:
            item = self.alert_images.get(camera)
        return (item[0], self.clock() - item[1]) if item else (None, None)


def subscribe_live(session, keys, live: LiveState) -> list:
    """Detections, alerts (with snapshots) and live pictures into ``live``; the entities, for
    closing. The commands go through the follower (the consumer rule), not here."""

    def attachment(s) -> bytes | None:
        return s.attachment.to_bytes() if s.attachment is not None else None

    return [
        session.declare_subscriber(keys.detections,
                                   lambda s: live.on_detections(s.payload.to_bytes())),
        session.declare_subscriber(keys.alert,
                                   lambda s: live.on_alert(s.payload.to_bytes(), attachment(s))),
        session.declare_subscriber(keys.preview,
                                   lambda s: live.on_preview(s.payload.to_bytes(), attachment(s))),
    ]


class LiveRenderer:
    """JPEG per camera: background, zones (hits thicker), person boxes; cached briefly."""

    def __init__(self, live: LiveState, cell_of, references: dict[str, Path],
                 min_render_s: float = 0.2) -> None:
        self.live = live
        self.cell_of = cell_of  # () -> Cell, the zone file as it is on disk now
        self.references = references
        self.min_render_s = min_render_s
        self._cache: dict[str, tuple[float, bytes]] = {}
        self._lock = threading.Lock()

    def background(self, cell: Cell, camera: str) -> tuple[np.ndarray, str]:
        jpeg, age = self.live.preview(camera)
        if jpeg is not None and age is not None and age <= PREVIEW_FRESH_S:
            img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
            if img is not None:
                cam = cell.cameras[camera]
                if img.shape[:2] != (cam.height, cam.width):  # zones are in camera pixels
                    img = cv2.resize(img, (cam.width, cam.height))
                return img, f"live picture, {age:.1f} s old"
        jpeg, age = self.live.alert_image(camera)
        if jpeg is not None and age is not None and age <= SNAPSHOT_FRESH_S:
            img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
            if img is not None:
                return img, f"alert snapshot, {age:.0f} s ago"
        return reference_image(cell, camera, self.references.get(camera)), "reference image"

    def jpeg(self, camera: str) -> bytes:
        now = time.monotonic()
        with self._lock:
            cached = self._cache.get(camera)
            if cached is not None and now - cached[0] < self.min_render_s:
                return cached[1]
            cell = self.cell_of()
            img, label = self.background(cell, camera)
            det, age = self.live.latest_detections(camera)
            fresh = det is not None and age is not None and age <= DETECTIONS_FRESH_S
            hits = [str(h.get("zone_id")) for h in (det or {}).get("hits", [])
                    if isinstance(h, dict)] if fresh else []
            img = draw_zones(img, cell, camera, hits)
            cam = cell.cameras[camera]
            if fresh:
                _draw_boxes(img, det or {}, img.shape[1] / cam.width, img.shape[0] / cam.height)
            note = f"{camera}: {label}; " + (
                "detections now" if fresh else
                "no detections" + (f" for {age:.0f} s" if age is not None else " yet"))
            cv2.putText(img, note, (10, img.shape[0] - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                        (255, 255, 255), 2, cv2.LINE_AA)
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
            data = buf.tobytes() if ok else b""
            self._cache[camera] = (now, data)
            return data


def reference_image(cell: Cell, camera: str, path: Path | None) -> np.ndarray:
    """The camera's reference image at its resolution, or a grey canvas of that size."""
    cam = cell.cameras[camera]
    if path is not None:
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is not None:
            if img.shape[:2] != (cam.height, cam.width):
                img = cv2.resize(img, (cam.width, cam.height))
            return img
    img = np.full((cam.height, cam.width, 3), 64, np.uint8)
    cv2.putText(img, f"{camera}: no reference image (--reference {camera}=FILE)",
                (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (200, 200, 200), 2, cv2.LINE_AA)
    return img


def _draw_boxes(img: np.ndarray, det: dict, sx: float, sy: float) -> None:
    boxes = det.get("boxes_px") or []
    hit_persons = {h.get("person") for h in det.get("hits", []) if isinstance(h, dict)}
    for k, box in enumerate(boxes[:200]):
        try:
            x1, y1, x2, y2 = (float(v) for v in box[:4])
        except (TypeError, ValueError):
            continue
        colour = (0, 0, 255) if k in hit_persons else (255, 255, 0)
        cv2.rectangle(img, (int(x1 * sx), int(y1 * sy)), (int(x2 * sx), int(y2 * sy)), colour,
                      3, cv2.LINE_AA)


def _json(payload: bytes) -> dict | None:
    try:
        body = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    return body if isinstance(body, dict) else None


def _camera_of(payload: bytes) -> str | None:
    body = _json(payload)
    frame = (body or {}).get("frame")
    cam = frame.get("camera_id") if isinstance(frame, dict) else None
    return str(cam) if cam is not None else None
