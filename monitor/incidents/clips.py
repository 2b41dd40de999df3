"""An incident's clip: annotated frames (the replay's overlay and the clock)
into an H.264 MP4 through PyAV, each frame at its capture time (variable frame rate in a
fixed time base), so a clip shows the real timing around the event."""

from __future__ import annotations

import fractions
from pathlib import Path

import cv2
import numpy as np

from monitor.records.annotate import annotate
from monitor.timetext import TimeText
from monitor.zones.draw import ZoneDrawCache

CODEC = "H.264 (libx264 via PyAV)"


def overlay(image: np.ndarray, result, cell, camera_id: str, watch: list,
            when: TimeText | None = None,
            zone_cache: ZoneDrawCache | None = None) -> np.ndarray:
    """The replay's overlay (``monitor.records.annotate``): the header with camera and time, zones
    with labels apart and a legend, each person with the track id the commands use and the floor
    range behind a hit, health, the state bar with the command's description. ``when``: the times as
    text (live: wall clock); None: seconds of the video. ``zone_cache``: the camera's zone
    drawing kept between frames (``ZoneDrawCache``)."""
    return annotate(image, result, cell, camera_id, watch, when=when,
                    zone_cache=zone_cache)[0]


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
