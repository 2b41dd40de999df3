"""Decoding a video file's frames: PyAV (FFmpeg's libraries, a dependency of the monitor) and
OpenCV's FFmpeg backend, behind one small interface (``open`` the file, ``read`` the next
frame with its container time).

PyAV decodes first: on a 2-core host it spends about a fifth less CPU per 1080p frame than
``cv2.VideoCapture`` for the same BGR pixels (both convert yuv420p with FFmpeg's swscale: the
images are identical), and its time per frame does not grow when another thread holds the
other core (benchmarks/frames.py). A file PyAV cannot open or decode a
first frame of goes to OpenCV, whose failure ``VideoFileReader`` diagnoses as before.
"""

from __future__ import annotations

import math
from pathlib import Path

import av
import cv2
import numpy as np


class Decoder:
    """What ``VideoFileReader`` needs of a decoder. ``open`` returns the first frame (None:
    no frame can be decoded, the decoder is closed); ``read`` the next (None at the end or at
    a break) with its container time in milliseconds (NaN: the container has none)."""

    name = ""
    fps: float | None = None
    frame_count: int = 0  # declared by the container; 0 if unknown
    codec: str = "unknown"

    def open(self, path: Path) -> tuple[np.ndarray, float] | None:
        raise NotImplementedError

    def read(self) -> tuple[np.ndarray, float] | None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


def _fourcc_text(value: float) -> str:
    code = int(value) if math.isfinite(value) else 0
    text = "".join(chr((code >> 8 * k) & 0xFF) for k in range(4))
    return text if code and text.isprintable() else "unknown"


class OpenCvDecoder(Decoder):
    """``cv2.VideoCapture`` with its FFmpeg backend."""

    name = "opencv"

    def __init__(self) -> None:
        self._cap: cv2.VideoCapture | None = None

    def open_capture(self, path: Path) -> bool:
        """Open the file (False: FFmpeg cannot) and read its declared facts."""
        cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            cap.release()
            return False
        fps = cap.get(cv2.CAP_PROP_FPS)
        self.fps = fps if math.isfinite(fps) and fps > 0 else None
        count = cap.get(cv2.CAP_PROP_FRAME_COUNT)
        self.frame_count = int(count) if math.isfinite(count) and count > 0 else 0
        self.codec = _fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
        self._cap = cap
        return True

    def open(self, path: Path) -> tuple[np.ndarray, float] | None:
        if not self.open_capture(path):
            return None
        first = self.read()
        if first is None:
            self.close()
        return first

    def read(self) -> tuple[np.ndarray, float] | None:
        if self._cap is None:
            return None
        ok, image = self._cap.read()
        if not ok or image is None:
            return None
        return image, self._cap.get(cv2.CAP_PROP_POS_MSEC)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
        self._cap = None


class PyAvDecoder(Decoder):
    """PyAV: the container's video stream decoded frame by frame, converted to BGR."""

    name = "pyav"

    def __init__(self) -> None:
        self._container = None
        self._frames = None  # the decode iterator

    def open(self, path: Path) -> tuple[np.ndarray, float] | None:
        try:
            container = av.open(str(path))
        except (av.FFmpegError, OSError, ValueError):  # not a container FFmpeg reads
            return None
        stream = container.streams.video[0] if container.streams.video else None
        if stream is None or stream.codec_context is None:  # no video, or a codec PyAV lacks
            container.close()
            return None
        rate = stream.average_rate or stream.guessed_rate
        self.fps = float(rate) if rate and float(rate) > 0 else None
        self.frame_count = max(0, int(stream.frames or 0))
        tag = stream.codec_context.codec_tag
        self.codec = tag if tag and tag.isprintable() and tag.strip() else stream.codec_context.name
        self._container, self._frames = container, container.decode(stream)
        first = self.read()
        if first is None:
            self.close()
        return first

    def read(self) -> tuple[np.ndarray, float] | None:
        if self._frames is None:
            return None
        try:
            frame = next(self._frames)
        except (StopIteration, av.FFmpegError, EOFError):  # the end, or a break in the file
            return None
        t = frame.time
        return frame.to_ndarray(format="bgr24"), math.nan if t is None else t * 1e3

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
        self._container, self._frames = None, None
