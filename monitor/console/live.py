"""The console's live view: the cell's verdict, the live picture, detections and alert
snapshots, drawn.

The picture is the monitor's live preview (``monitor.bus.preview``: a small JPEG per camera at a low
rate, ``[preview] fps``, signed with the monitor's key; a preview not signed by a pinned key is
not shown). It is live only while its *signed* capture time is within ``LIVE_WITHIN_S`` of the
console's clock, and a camera's picture is replaced only by one whose signed sequence grows
(within a boot; a new boot only with a later capture): genuinely signed pictures recorded earlier
and sent again are refused and counted, never the live picture (issue 48: aged by arrival, a
replayed empty cell showed in 3 to 5 of 8 samples while a person stood inside). Without a live
picture the view says "no live picture" in red over the snapshot of a recent alert of that
camera, else the camera's reference image (``--reference cam0=FILE``). Alerts count only when
signed by a pinned key (``monitor.wire.alerts.read_signed_alert``): the others are dropped and
counted (``alerts_refused``), never listed. Over it the console
draws the zones (the same drawing as ``monitor zones preview``), the zones hit, the person
boxes of the newest detections and the lost persons' areas they carry (``live_areas``: why the
cell is held). The state and its reasons come from the consumer rule
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
from monitor.bus.preview import MAX_PREVIEW_BYTES, Preview, read_preview
from monitor.console.live_areas import area_list, draw_live_areas, draw_live_pockets, pocket_list
from monitor.types import Alert
from monitor.wire.alerts import read_signed_alert
from monitor.zones.draw import ZoneDrawCache, draw_zones
from monitor.zones.files import Cell

MAX_DETECTIONS_BYTES = 1_000_000  # a detections message larger than this is not drawn
SNAPSHOT_FRESH_S = 30.0  # an alert snapshot older than this gives way to the reference image
DETECTIONS_FRESH_S = 2.0  # older detections are not drawn as current
LIVE_WITHIN_S = 1.0  # a picture is live while its signed capture time is this close to now
MAX_PREVIEW_CAMERAS = 64  # pictures of more cameras than this are not kept


class LiveState:
    """The newest of everything the live page shows; an ``Output`` of the follower."""

    name = "console"

    def __init__(self, clock=time.monotonic, preview_keys: tuple = (),
                 require_signed: bool = True, preview_key: str = "", alert_key: str = "",
                 wall=time.time) -> None:
        self.clock = clock
        self.wall = wall  # the console's wall clock: signed capture times are judged on it
        self._lock = threading.Lock()
        self.snapshot: SafetySnapshot | None = None
        self.detections: dict[str, tuple[bytes, float]] = {}  # camera -> (payload, received)
        self.alert_images: dict[str, tuple[bytes, float]] = {}  # camera -> (jpeg, received)
        self.alerts: deque[dict] = deque(maxlen=50)
        # live pictures: checked against the monitor's keys (--monitor-key) unless the console
        # runs --unauthenticated
        self.preview_keys, self.require_signed = tuple(preview_keys), require_signed
        self.preview_key, self.alert_key = preview_key, alert_key
        self.previews: dict[str, Preview] = {}  # camera -> its newest accepted picture
        self.previews_refused = 0  # not signed, too large, not a picture, too many cameras
        self.previews_stale = 0  # signed, but its capture time is not within LIVE_WITHIN_S
        self.previews_replayed = 0  # signed and recent, but its sequence does not grow
        self.alerts_refused = 0  # alerts without a valid signature: dropped, never listed

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
        """An alert of the bus: listed only when signed by a pinned key (``--unauthenticated``:
        any, its attachment the JPEG), else dropped and counted."""
        if self.require_signed:
            read = read_signed_alert(payload, attachment, self.alert_key, self.preview_keys)
            if read is None:
                with self._lock:
                    self.alerts_refused += 1
                return
            body, jpeg = read
        else:
            body, jpeg = _json(payload), attachment
            if body is None:
                return
        entry = {k: body.get(k) for k in ("kind", "severity", "message", "source", "wall")}
        entry["received"] = time.time()
        with self._lock:
            self.alerts.appendleft(entry)
            if jpeg and jpeg[:2] == b"\xff\xd8":  # a JPEG, by its magic
                self.alert_images[str(body.get("source", ""))] = (jpeg, self.clock())

    def on_preview(self, payload: bytes, attachment: bytes | None) -> None:
        """A live picture: kept (newest per camera) only when it is a signed preview captured
        within ``LIVE_WITHIN_S`` of now whose sequence grows (see the module's docstring)."""
        preview = read_preview(payload, attachment, self.preview_key, self.preview_keys,
                               self.require_signed) if len(payload) <= MAX_PREVIEW_BYTES \
            else None
        now = self.wall()
        with self._lock:
            if preview is None or (preview.camera not in self.previews
                                   and len(self.previews) >= MAX_PREVIEW_CAMERAS):
                self.previews_refused += 1
                return
            if not _live(preview, now):
                self.previews_stale += 1
                return
            last = self.previews.get(preview.camera)
            if last is not None and not _follows(preview, last):
                self.previews_replayed += 1
                return
            self.previews[preview.camera] = preview

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
            fresh = {cam: body for cam, (body, t) in self.detections.items()
                     if self.clock() - t <= DETECTIONS_FRESH_S}
            now = self.wall()
            pictures = {cam: p for cam, p in self.previews.items()}
            counts = {"previews_refused": self.previews_refused,
                      "previews_stale": self.previews_stale,
                      "previews_replayed": self.previews_replayed,
                      "alerts_refused": self.alerts_refused}
        body: dict[str, Any] = {
            "state": "STOP", "reason": "console starting", "alerts": alerts,
            "detections_age_s": {c: round(a, 2) for c, a in seen.items()},
            # the signed capture's age on the console's clock, and whether it is live now
            "preview_age_s": {c: round(now - p.capture_wall, 2) for c, p in pictures.items()
                              if p.capture_wall is not None},
            "live_picture": {c: _live(p, now) for c, p in pictures.items()},
            # where lost persons could be, per camera of fresh detections: why it is held
            "areas": {c: area_list(_json(b)) for c, b in fresh.items()},
            # the hidden pockets with their counts: what ends a hold behind a cabinet
            "pockets": {c: pocket_list(_json(b)) for c, b in fresh.items()}, **counts}
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
        """The live picture of ``camera`` and its signed age (s), or (None, None) when there
        is none within ``LIVE_WITHIN_S`` of now: never an older picture as the live one."""
        with self._lock:
            item = self.previews.get(camera)
        now = self.wall()
        if item is None or item.capture_wall is None or not _live(item, now):
            return None, None
        return item.jpeg, now - item.capture_wall

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
        self._zone_drawing: dict[str, ZoneDrawCache] = {}  # per camera, under the lock
        self._lock = threading.Lock()

    def background(self, cell: Cell, camera: str) -> tuple[np.ndarray, str, bool]:
        """The picture under the drawing, what it is, and whether it is the live picture."""
        jpeg, age = self.live.preview(camera)  # only a picture within LIVE_WITHIN_S of now
        if jpeg is not None and age is not None:
            img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
            if img is not None:
                cam = cell.cameras[camera]
                if img.shape[:2] != (cam.height, cam.width):  # zones are in camera pixels
                    img = cv2.resize(img, (cam.width, cam.height))
                return img, f"live picture, {max(0.0, age):.1f} s old", True
        jpeg, age = self.live.alert_image(camera)
        if jpeg is not None and age is not None and age <= SNAPSHOT_FRESH_S:
            img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
            if img is not None:
                return img, f"alert snapshot, {age:.0f} s ago", False
        return reference_image(cell, camera, self.references.get(camera)), "reference image", \
            False

    def jpeg(self, camera: str) -> bytes:
        now = time.monotonic()
        with self._lock:
            cached = self._cache.get(camera)
            if cached is not None and now - cached[0] < self.min_render_s:
                return cached[1]
            cell = self.cell_of()
            img, label, is_live = self.background(cell, camera)
            det, age = self.live.latest_detections(camera)
            fresh = det is not None and age is not None and age <= DETECTIONS_FRESH_S
            hits = [str(h.get("zone_id")) for h in (det or {}).get("hits", [])
                    if isinstance(h, dict)] if fresh else []
            # the camera's zone drawing kept between renders (the shadow behind the
            # occluders alone took 0.4 s to compute on the demo cell)
            img = draw_zones(img, cell, camera, hits,
                             cache=self._zone_drawing.setdefault(camera, ZoneDrawCache()))
            cam = cell.cameras[camera]
            if fresh:
                sx, sy = img.shape[1] / cam.width, img.shape[0] / cam.height
                draw_live_areas(img, det or {}, sx, sy)
                draw_live_pockets(img, det or {}, sx, sy)
                _draw_boxes(img, det or {}, img.shape[1] / cam.width, img.shape[0] / cam.height)
            note = f"{camera}: {label}; " + (
                "detections now" if fresh else
                "no detections" + (f" for {age:.0f} s" if age is not None else " yet"))
            cv2.putText(img, note, (10, img.shape[0] - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                        (255, 255, 255), 2, cv2.LINE_AA)
            if not is_live:  # never let a snapshot or the reference pass for the cell now
                draw_no_live_picture(img)
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
            data = buf.tobytes() if ok else b""
            self._cache[camera] = (now, data)
            return data


NO_LIVE_PICTURE = "NO LIVE PICTURE"
NO_LIVE_BAR_PX = 48  # the red bar's height at the top of the view


def draw_no_live_picture(img: np.ndarray) -> None:
    """A red bar across the top saying "NO LIVE PICTURE" (in place)."""
    cv2.rectangle(img, (0, 0), (img.shape[1], NO_LIVE_BAR_PX), (0, 0, 220), -1)
    cv2.putText(img, f"{NO_LIVE_PICTURE}: not the cell now", (12, 34),
                cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 2, cv2.LINE_AA)


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


def _live(preview: Preview, now: float) -> bool:
    """Whether ``preview``'s signed capture time is within ``LIVE_WITHIN_S`` of ``now``."""
    t = preview.capture_wall
    return t is not None and abs(now - t) <= LIVE_WITHIN_S


def _follows(new: Preview, last: Preview) -> bool:
    """Whether ``new`` may replace ``last``: a later picture of the same boot (its signed
    ``seq`` grows with every picture; the frame's own sequence may start again when a camera
    reconnects), or of another boot (a restarted monitor) a later capture."""
    if new.boot == last.boot and new.instance == last.instance:
        return new.seq > last.seq
    return (new.capture_wall or 0.0) > (last.capture_wall or 0.0)


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
