"""``[preview]``: a small live picture per camera on ``<prefix>safety/preview``, for the console.

An optional extra around the safety loop, like the incident recorder: the loop's sink only
*offers* a camera's frame (a reference into one slot per camera, newest wins: a dict store and
an event, never a wait); a worker thread downsizes, encodes, signs and publishes it. The
publisher drops under congestion at a low priority, so a busy worker, a slow link or a console
that is killed cost the decision nothing but the offer (``benchmarks/preview.py`` measures the
loop's capture->command latency with and without it). A fault of the preview is counted in the
status (``preview``), never raised into the loop.

The message (``workcell.safety.preview/1``): the bus envelope (cell, seq, mono, wall,
instance, boot, config_hash), ``camera``, ``frame_seq``, ``capture_mono``, ``capture_wall`` (the
capture's time on the wall clock: the frame's monotonic capture time carried over to the wall
clock at publication; null when the frame's time is not this host's monotonic clock), the
camera's size (``width``, ``height``), the picture's size and the JPEG as base64 (``jpeg``); the
sample's attachment is the Ed25519 signature of the payload with the monitor's key, as for
commands (``monitor.wire.signing``), so a console that pins the key shows no picture someone
else put there. The capture time, the frame's sequence and the boot are under the signature:
the console shows a picture as live only while its capture time is within a second of its own
clock and each camera's sequence grows (``monitor.console.live``), so genuinely signed pictures
recorded earlier and sent again are never the live picture (issue 48).
"""

from __future__ import annotations

import base64
import contextlib
import json
import logging
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated

import cv2
import numpy as np
import zenoh
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey
from pydantic import Field

from monitor.schema import Float, Int, section
from monitor.wire.signing import Signer, load_private_key, verify

PREVIEW_SCHEMA = "workcell.safety.preview/1"
MAX_PREVIEW_BYTES = 2_000_000  # a preview message larger than this is not read
MAX_CAPTURE_AGE_S = 60.0  # a frame older than this at publication has no wall time we trust
STATUS_EVERY_S = 2.0  # the counters go into the status queryable at most this often


@section("preview")
class PreviewConfig:
    # pictures a second per camera; 0 = no preview (nothing is declared on the bus). The
    # console shows a picture as live for 1 s after its capture: below ~1.5 it is "no live
    # picture" between two pictures
    fps: Annotated[Float, Field(ge=0, le=5)] = 2.0
    # the picture is scaled down to at most this width (its height in proportion)
    max_width: Annotated[Int, Field(ge=64, le=1920)] = 640
    jpeg_quality: Annotated[Int, Field(ge=20, le=95)] = 70


def preview_jpeg(image: np.ndarray, max_width: int, quality: int) -> tuple[bytes, int, int]:
    """The picture as JPEG, at most ``max_width`` wide: (bytes, width, height)."""
    h, w = image.shape[:2]
    if w > max_width:
        h, w = max(1, round(h * max_width / w)), max_width
        image = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("the JPEG encoder refused the frame")
    return buf.tobytes(), w, h


@dataclass(frozen=True)
class Preview:
    """One received preview, checked."""

    camera: str
    jpeg: bytes
    frame_seq: int
    wall: float
    instance: str
    signed: bool
    capture_wall: float | None = None  # None: no capture time the console can trust
    boot: str = ""
    seq: int = -1  # the picture's sequence in its boot (grows with every picture sent)


def read_preview(payload: bytes, signature: bytes | None, key_expr: str,
                 public_keys: tuple[Ed25519PublicKey, ...], require_signed: bool
                 ) -> Preview | None:
    """The preview in ``payload``, or None when it is too large, not ours, not signed by one of
    ``public_keys`` (when ``require_signed``) or not a JPEG."""
    if len(payload) > MAX_PREVIEW_BYTES:
        return None
    signed = any(verify(k, key_expr, payload, signature) for k in public_keys)
    if require_signed and not signed:
        return None
    try:
        body = json.loads(payload)
        if not isinstance(body, dict) or body.get("schema") != PREVIEW_SCHEMA:
            return None
        jpeg = base64.b64decode(str(body["jpeg"]), validate=True)
        capture = body.get("capture_wall")
        capture_wall = float(capture) if isinstance(capture, int | float) and \
            not isinstance(capture, bool) and math.isfinite(capture) else None
        preview = Preview(str(body["camera"])[:64], jpeg, int(body.get("frame_seq", -1)),
                          float(body.get("wall", 0.0)), str(body.get("instance", ""))[:128],
                          signed, capture_wall, str(body.get("boot", ""))[:128],
                          int(body.get("seq", -1)))
    except (ValueError, KeyError, TypeError, UnicodeDecodeError, RecursionError):
        return None
    return preview if jpeg[:2] == b"\xff\xd8" else None  # a JPEG, by its magic


class PreviewSink:
    """A sink of the driver: offers each camera's frame at most ``fps`` times a second to a
    worker that encodes and publishes it. ``put(payload, attachment)`` sends one message;
    ``who`` is the envelope's fixed part (cell, instance, boot, config_hash)."""

    def __init__(self, config: PreviewConfig, put: Callable[[bytes, bytes | None], None],
                 key_expr: str, who: Callable[[], dict], signer: Signer | None = None,
                 on_status: Callable[[dict], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.interval = 1.0 / config.fps if config.fps > 0 else float("inf")
        self._put, self.key_expr, self._who, self._signer = put, key_expr, who, signer
        self._on_status = on_status
        self._clock = clock
        self._lock = threading.Lock()
        self._slots: dict[str, object] = {}  # camera -> newest offered frame
        self._last_offer: dict[str, float] = {}  # camera -> capture time of its last offer
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._seq = 0
        self.counts = {"offered": 0, "replaced": 0, "published": 0, "errors": 0}
        self._status_at = -float("inf")
        self._thread = threading.Thread(target=self._work, name="preview", daemon=True)
        self._thread.start()

    # --- the loop's side: never waits -----------------------------------------------------
    def on_step(self, step) -> None:
        if step.frame is not None:
            self.offer(step.frame)

    def offer(self, frame) -> bool:
        """Hand ``frame`` (a ``monitor.frames.Frame``) to the worker if its camera is due;
        an unsent older one of that camera is replaced. True when taken."""
        try:
            info = frame.info
            last = self._last_offer.get(info.camera_id)
            if last is not None and info.capture_time - last < self.interval * 0.999:
                return False
            self._last_offer[info.camera_id] = info.capture_time
            with self._lock:
                if info.camera_id in self._slots:
                    self.counts["replaced"] += 1
                self._slots[info.camera_id] = frame
                self.counts["offered"] += 1
            self._wake.set()
            return True
        except Exception:  # an extra: its faults never reach the safety loop
            self.counts["errors"] += 1
            return False

    def close(self, timeout: float = 1.0) -> None:
        self._closing.set()
        self._wake.set()
        self._thread.join(timeout)

    # --- the worker -------------------------------------------------------------------------
    def _work(self) -> None:
        with contextlib.suppress(OSError, AttributeError):
            # this thread only: the loop's threads keep their priority over the encoding
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
        while not self._closing.is_set():
            self._wake.wait()
            self._wake.clear()
            while not self._closing.is_set():
                with self._lock:
                    if not self._slots:
                        break
                    camera = next(iter(self._slots))
                    frame = self._slots.pop(camera)
                try:
                    self._publish(frame)
                    self.counts["published"] += 1
                except Exception:  # counted in the status; the next frame tries again
                    self.counts["errors"] += 1
                self._report()

    def _publish(self, frame) -> None:
        info = frame.info
        jpeg, w, h = preview_jpeg(frame.image, self.config.max_width, self.config.jpeg_quality)
        self._seq += 1
        mono, wall = self._clock(), time.time()
        age = mono - info.capture_time
        # the capture on the wall clock (signed): a frame time of another clock (a video's) or
        # implausibly old gives none, and the console then never shows it as live
        capture_wall = round(wall - age, 6) if 0.0 <= age <= MAX_CAPTURE_AGE_S else None
        body = {"schema": PREVIEW_SCHEMA, **self._who(), "seq": self._seq,
                "mono": mono, "wall": wall, "camera": info.camera_id,
                "frame_seq": info.seq, "capture_mono": info.capture_time,
                "capture_wall": capture_wall,
                "width": info.width, "height": info.height, "jpeg_width": w,
                "jpeg_height": h, "jpeg": base64.b64encode(jpeg).decode()}
        payload = json.dumps(body).encode()
        signature = self._signer.sign(self.key_expr, payload) if self._signer else None
        self._put(payload, signature)

    def _report(self) -> None:
        now = self._clock()
        if self._on_status is None or now - self._status_at < STATUS_EVERY_S:
            return
        self._status_at = now
        with contextlib.suppress(Exception):
            self._on_status({"fps": self.config.fps, "max_width": self.config.max_width,
                             **self.counts})


def start_preview(config: PreviewConfig, bus, event: Callable) -> tuple | None:
    """The preview sink on the bus's session and its close(), or None when ``fps`` is 0 or
    the publisher cannot be declared (then the monitor runs without it, and says so)."""
    if config.fps <= 0:
        return None
    key = bus.keys.preview
    try:
        publisher = bus.session.declare_publisher(
            key, encoding="application/json", priority=zenoh.Priority.DATA_LOW,
            congestion_control=zenoh.CongestionControl.DROP)
    except Exception as exc:
        event("preview not declared: the console shows no live picture", logging.WARNING,
              error=str(exc))
        return None
    bus_config = bus.config

    def who() -> dict:
        return {"cell": bus_config.cell, "instance": bus_config.instance, "boot": bus.boot,
                "config_hash": bus.config.config_hash,
                **({"role": bus_config.role} if bus_config.role else {})}

    # signed with the monitor's key, like its commands (read again: the bus keeps its own)
    signer = load_private_key(bus_config.signing_key) if bus_config.signing_key else None
    sink = PreviewSink(config, lambda payload, sig: publisher.put(payload, attachment=sig),
                       key, who, signer,
                       on_status=lambda counts: bus.update_status(preview=counts))
    event("live preview", key=key, fps=config.fps, max_width=config.max_width)

    def close() -> None:
        sink.close()
        with contextlib.suppress(Exception):
            publisher.undeclare()

    return sink, close
