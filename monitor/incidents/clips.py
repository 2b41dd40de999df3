"""An incident's clip: annotated frames (the replay's overlay plus track ids and the clock)
into an H.264 MP4 through PyAV, each frame at its capture time (variable frame rate in a
fixed time base), so a clip shows the real timing around the event."""

from __future__ import annotations

import fractions
from pathlib import Path

import cv2
import numpy as np

CODEC = "H.264 (libx264 via PyAV)"


class ZoneLayer:
    """``draw_zones`` for a stream of frames: zones are drawn as translucent fills and opaque
    outlines, so the drawing is ``out = image * a + b`` per pixel. ``a`` and ``b`` are measured
    once per (camera, zones hit, size) from two drawings, then each frame costs one multiply
    and add (~5 ms at 720p instead of a full drawing, ~200 ms). Keeps ``keep`` layers."""

    def __init__(self, keep: int = 4) -> None:
        self.keep = keep
        self.layers: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}

    def __call__(self, image: np.ndarray, cell, camera_id: str, hits) -> np.ndarray:
        from monitor.zones import draw_zones

        key = (camera_id, frozenset(hits), image.shape)
        layer = self.layers.pop(key, None)
        if layer is None:
            dark = draw_zones(np.zeros(image.shape, np.uint8), cell, camera_id, hits)
            light = draw_zones(np.full(image.shape, 255, np.uint8), cell, camera_id, hits)
            layer = (cv2.subtract(light, dark), dark)  # a * 255, b
        self.layers[key] = layer  # most recently used last
        while len(self.layers) > self.keep:
            self.layers.pop(next(iter(self.layers)))
        return cv2.add(cv2.multiply(image, layer[0], scale=1 / 255), layer[1])


def overlay(image: np.ndarray, result, cell, camera_id: str, watch: list,
            zones: ZoneLayer | None = None) -> np.ndarray:
    """Boxes, zones, state, reasons and health (``monitor.replay.annotate``), plus each
    person's track id and the camera (the recorder stamps the time to the incident)."""
    from monitor.replay import annotate
    from monitor.zones import draw_zones

    out = annotate(image, result, cell, camera_id, watch, zones or draw_zones)
    persons = result.persons
    if persons is not None:
        for k, (x1, _, _, y2) in enumerate(persons.boxes_px):
            if k < len(result.track_ids):
                cv2.putText(out, f"id {result.track_ids[k]}", (int(x1) + 4, int(y2) - 8),
                            cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2)
    cv2.putText(out, camera_id, (12, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7,
                (255, 255, 255), 2, cv2.LINE_AA)
    return out


class ClipWriter:
    """``write(bgr, t)`` frames with their capture times, ``close()``. The first frame sets the
    size (yuv420p needs even sizes: an odd last row/column is dropped)."""

    TIME_BASE = fractions.Fraction(1, 1000)  # ms

    def __init__(self, path: Path, fps: float) -> None:
        self.path = path
        self.fps = fps
        self.container = None
        self.stream = None
        self.t0: float | None = None
        self.last_pts = -1
        self.frames = 0

    def _open(self, shape: tuple[int, ...]) -> None:
        import av

        self.av = av
        self.container = av.open(str(self.path), mode="w")
        stream = self.container.add_stream(
            "libx264", rate=fractions.Fraction(self.fps).limit_denominator(1001))
        stream.width, stream.height = shape[1] // 2 * 2, shape[0] // 2 * 2
        stream.pix_fmt = "yuv420p"
        stream.time_base = self.TIME_BASE
        stream.codec_context.time_base = self.TIME_BASE
        # ultrafast + zerolatency: the least CPU beside the safety loop, and no lookahead
        stream.options = {"preset": "ultrafast", "crf": "26", "tune": "zerolatency"}
        self.stream = stream

    def write(self, image: np.ndarray, t: float) -> None:
        if self.container is None:
            self._open(image.shape)
            self.t0 = t
        h, w = self.stream.height, self.stream.width
        if image.shape[0] < h or image.shape[1] < w:
            image = cv2.resize(image, (w, h))
        frame = self.av.VideoFrame.from_ndarray(np.ascontiguousarray(image[:h, :w]),
                                                format="bgr24")
        pts = max(self.last_pts + 1, round((t - self.t0) / self.TIME_BASE))
        frame.pts, frame.time_base = pts, self.TIME_BASE
        self.last_pts = pts
        for packet in self.stream.encode(frame):
            self.container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        if self.container is None:
            return
        try:
            for packet in self.stream.encode():
                self.container.mux(packet)
        finally:
            self.container.close()
            self.container = None
