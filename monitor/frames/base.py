"""What every frame source shares: the frame, the source protocol, source kinds, URL
redaction, frame times from container timestamps and the reconnect backoff."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable
from urllib.parse import urlsplit, urlunsplit

import numpy as np

from monitor.errors import InputError
from monitor.types import FrameInfo

Clock = Callable[[], float]
Size = tuple[int, int]  # (width, height) in pixels

IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm",
                            ".pgm"})
URL_SCHEMES = ("rtsp", "rtsps", "rtmp", "http", "https", "udp", "tcp", "srt")


@dataclass(frozen=True)
class Frame:
    """One image and where/when it was taken.

    ``image`` is BGR uint8 (height, width, 3). ``info.capture_time`` is the monotonic clock at grab
    time for live sources, or the video's own time (seconds) for files and synthetic scenes.
    """

    image: np.ndarray
    info: FrameInfo


@runtime_checkable
class FrameSource(Protocol):
    """Something that yields frames one by one. Not thread-safe: one reader at a time.

    ``read()`` returns the next frame, ``None`` at the regular end of the stream (end of a file),
    and raises :class:`InputError` when the source is lost or broken (the grabber then reconnects
    by calling ``close()`` and ``open()``). ``open()`` may be called again after ``close()``.
    """

    camera_id: str
    description: str  # for messages; credentials removed
    fps: float | None  # nominal frames per second, None if unknown

    @property
    def is_open(self) -> bool: ...

    def open(self) -> None: ...

    def read(self) -> Frame | None: ...

    def close(self) -> None: ...


class TruncatedVideoError(InputError):
    """A video ended before its declared frame count: the frames before the break were read."""

    def __init__(self, description: str, frame_index: int, time_s: float, frames_expected: int):
        self.frame_index = frame_index  # first frame that could not be read (= frames read)
        self.time_s = time_s  # video time where it broke, seconds
        self.frames_expected = frames_expected
        super().__init__(f"{description}: truncated: broke at frame {frame_index} "
                         f"(t={time_s:.3f} s) of {frames_expected}; "
                         f"{frame_index} frames were read")


# --- pure helpers -------------------------------------------------------------------------------

def one_line(text: str) -> str:
    """Collapse whitespace so a message from a library fits on one line."""
    return " ".join(str(text).split())


def check_frame_size(width: int, height: int, expected: Size | None, where: str) -> None:
    """Raise InputError when a frame is not ``expected`` = (width, height) pixels.

    Zone polygons are pixels of one camera resolution; another size would put them elsewhere.
    """
    if expected is not None and (width, height) != tuple(expected):
        raise InputError(f"{where}: frame size {width}x{height} does not match the expected "
                         f"{expected[0]}x{expected[1]} (the zone file's camera)")


def source_kind(spec: str | int) -> str:
    """Which entry of ``SOURCE_KINDS`` handles a spec: camera, url, synthetic, image or file."""
    if isinstance(spec, int) or (isinstance(spec, str) and spec.strip().isdigit()):
        return "camera"
    text = spec.strip()
    if text.startswith("synthetic:"):
        return "synthetic"
    scheme = text.split("://", 1)[0].lower() if "://" in text else ""
    if scheme in URL_SCHEMES:
        return "url"
    if Path(text).suffix.lower() in IMAGE_SUFFIXES:
        return "image"
    return "file"


def redact_url(url: str) -> str:
    """The URL without its password, for logs and messages."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    host = parts.hostname or ""
    if parts.port is not None:
        host = f"{host}:{parts.port}"
    return urlunsplit(parts._replace(netloc=f"{parts.username}:***@{host}"))


def frame_time_s(pos_msec: float, index: int, fps: float | None, previous_s: float | None) -> float:
    """Video time of frame ``index`` in seconds.

    Uses the container's timestamp (``CAP_PROP_POS_MSEC``) when it is usable: finite and strictly
    after the previous frame (0 is accepted for the first frame only). Otherwise index / fps.
    Raises InputError when neither is available.
    """
    t = pos_msec / 1000.0 if math.isfinite(pos_msec) and pos_msec >= 0 else None
    if t is not None and (index == 0 or t > 0) and (previous_s is None or t > previous_s):
        return t
    if not fps or not math.isfinite(fps) or fps <= 0:
        raise InputError(f"frame {index} has no timestamp and the video no frame rate")
    t = index / fps
    if previous_s is not None and t <= previous_s:
        t = previous_s + 1.0 / fps
    return t


@dataclass(frozen=True)
class Backoff:
    """Exponential reconnect delays: ``initial_s * factor**attempt``, at most ``max_s``."""

    initial_s: float = 0.5
    max_s: float = 10.0
    factor: float = 2.0

    def __post_init__(self) -> None:
        if not (0 < self.initial_s <= self.max_s) or self.factor < 1:
            raise ValueError(f"Backoff: need 0 < initial_s <= max_s and factor >= 1, got {self}")

    def delay(self, attempt: int) -> float:
        """Seconds to wait before reconnect attempt ``attempt`` (0 = first after the loss)."""
        return min(self.max_s, self.initial_s * self.factor ** min(attempt, 64))
