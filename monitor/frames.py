"""Frame sources: cameras, video files, images, RTSP/HTTP streams and the synthetic demo scene.

Two ways to get frames:

- Replay reads a file frame by frame with :class:`VideoFileReader`; ``capture_time`` is the
  video's own clock (seconds from the container's timestamps), so the same file always gives the
  same times.
- The live service wraps any source in a :class:`LatestFrameGrabber`: a thread that keeps only the
  newest frame, stamps it with the monotonic clock at grab time, counts the frames nobody took,
  and reconnects with a bounded exponential backoff after a loss. Its ``connected``,
  ``last_frame_time`` and ``last_error`` let health and policy STOP on a lost camera.

Sources are made from a spec string by :func:`open_source` (``0``, ``video.mp4``, ``still.png``,
``rtsp://...``, ``http://...``, ``synthetic:demo``); the kinds are listed in ``SOURCE_KINDS``.

Images are BGR ``uint8`` arrays of shape (height, width, 3); sizes are ``(width, height)`` in
pixels. Every error a user can fix is an :class:`~monitor.errors.InputError` with a one-line
message naming the source and the fault.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable
from urllib.parse import urlsplit, urlunsplit

import cv2
import numpy as np

from monitor.errors import InputError
from monitor.scene import DemoScene, FrameTruth
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


def _fourcc_text(value: float) -> str:
    code = int(value) if math.isfinite(value) else 0
    text = "".join(chr((code >> 8 * k) & 0xFF) for k in range(4))
    return text if code and text.isprintable() else "unknown"


def _iso_boxes(path: Path) -> list[tuple[str, int]] | None:
    """Top-level ISO-BMFF (MP4/MOV) boxes as (type, payload bytes present), or None if the file
    is not one. A box cut by the end of the file reports only the bytes that are there."""
    boxes: list[tuple[str, int]] = []
    total = path.stat().st_size
    with path.open("rb") as f:
        offset = 0
        while offset + 8 <= total:
            f.seek(offset)
            header = f.read(16)
            size, kind = int.from_bytes(header[:4], "big"), header[4:8]
            if not kind.isascii() or not kind.decode("ascii").isprintable():
                break
            head = 8
            if size == 1 and len(header) == 16:
                size, head = int.from_bytes(header[8:16], "big"), 16
            elif size == 0:
                size = total - offset
            if size < head:
                break
            boxes.append((kind.decode("ascii"), min(size, total - offset) - head))
            offset += size
    if not boxes or boxes[0][0] != "ftyp":
        return None
    return boxes


def _diagnose_unopenable(path: Path, description: str) -> str:
    """Why FFmpeg could not open a file, as one line."""
    boxes = _iso_boxes(path)
    if boxes is None:
        return (f"{description}: not a video, or a container/codec that OpenCV's FFmpeg "
                f"cannot read")
    kinds = [k for k, _ in boxes]
    if "moov" not in kinds:
        return (f"{description}: truncated MP4: no 'moov' index (the recording was cut before "
                f"it was closed); no frame can be read")
    if sum(n for k, n in boxes if k == "mdat") == 0 and "moof" not in kinds:
        return f"{description}: the video contains no frames"
    return f"{description}: MP4 with a codec that OpenCV's FFmpeg cannot decode"


# --- file sources -------------------------------------------------------------------------------

class VideoFileReader:
    """Read a video file frame by frame with the video's own timestamps (seconds).

    ``open()`` checks everything it can up front (missing file, not a video, unknown codec, zero
    frames, frame size against ``expected_size``) and raises a one-line InputError. Iterating
    yields every frame that can be read; when the file breaks before its declared frame count, the
    frames before the break are yielded first and then :class:`TruncatedVideoError` is raised
    (``strict=True``), or iteration just ends and ``truncation`` holds the error
    (``strict=False``). So a caller processes what can be read and then learns where it broke.

    ``loop=True`` starts again at the end; video time keeps increasing across loops.
    """

    def __init__(self, path: str | Path, camera_id: str = "video", *,
                 expected_size: Size | None = None, strict: bool = True, loop: bool = False):
        self.path = Path(path)
        self.camera_id = camera_id
        self.description = str(path)
        self.expected_size = expected_size
        self.strict = strict
        self.loop = loop
        self.fps: float | None = None
        self.frame_count = 0  # declared by the container; 0 if unknown
        self.width = 0
        self.height = 0
        self.codec = "unknown"
        self.truncation: TruncatedVideoError | None = None
        self._cap: cv2.VideoCapture | None = None
        self._pending: np.ndarray | None = None  # first frame, read by open() to validate
        self._index = 0  # frames read in this pass
        self._seq = 0  # frames handed out over all loops
        self._time_offset = 0.0  # video time added per loop
        self._last_time: float | None = None  # within this pass

    @property
    def is_open(self) -> bool:
        return self._cap is not None

    def open(self) -> None:
        self.close()
        self._seq, self._time_offset = 0, 0.0
        self._open_pass()

    def _open_pass(self) -> None:
        desc = self.description
        if not self.path.exists():
            raise InputError(f"{desc}: no such file")
        if self.path.is_dir():
            raise InputError(f"{desc}: is a directory, not a video file")
        if self.path.stat().st_size == 0:
            raise InputError(f"{desc}: empty file (0 bytes)")
        cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            cap.release()
            raise InputError(_diagnose_unopenable(self.path, desc))
        fps = cap.get(cv2.CAP_PROP_FPS)
        self.fps = fps if math.isfinite(fps) and fps > 0 else None
        count = cap.get(cv2.CAP_PROP_FRAME_COUNT)
        self.frame_count = int(count) if math.isfinite(count) and count > 0 else 0
        self.codec = _fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
        ok, image = cap.read()
        if not ok or image is None:
            cap.release()
            if self.frame_count > 0:
                raise InputError(f"{desc}: cannot decode the first frame (codec {self.codec!r}): "
                                 f"unknown codec or corrupt data")
            raise InputError(f"{desc}: the video contains no frames")
        self.height, self.width = image.shape[:2]
        try:
            check_frame_size(self.width, self.height, self.expected_size, desc)
        except InputError:
            cap.release()
            raise
        self._cap, self._pending = cap, image
        self._index, self._last_time = 0, None
        self.truncation = None

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
        self._cap, self._pending = None, None

    def read(self) -> Frame | None:
        """Next frame, ``None`` at the end; raises TruncatedVideoError at a break (strict)."""
        cap = self._cap
        if cap is None:
            return None
        if self._pending is not None:
            image, self._pending = self._pending, None
        else:
            ok, image = cap.read()
            if not ok or image is None:
                return self._at_end()
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        t = frame_time_s(cap.get(cv2.CAP_PROP_POS_MSEC), self._index, self.fps, self._last_time)
        height, width = image.shape[:2]
        check_frame_size(width, height, self.expected_size,
                         f"{self.description} frame {self._index}")
        self._last_time = t
        self._index += 1
        info = FrameInfo(self.camera_id, self._seq, self._time_offset + t, width, height)
        self._seq += 1
        return Frame(image, info)

    def _at_end(self) -> Frame | None:
        if 0 < self._index < self.frame_count:
            # the next frame's time: one interval after the last frame read
            step = 1.0 / self.fps if self.fps else 0.0
            broke_at = (self._last_time or 0.0) + step
            self.truncation = TruncatedVideoError(self.description, self._index, broke_at,
                                                  self.frame_count)
            self.close()
            if self.strict:
                raise self.truncation
            return None
        if self.loop and self._index > 0:
            step = 1.0 / self.fps if self.fps else 0.0
            offset = self._time_offset + (self._last_time or 0.0) + step
            self.close()
            self._open_pass()
            self._time_offset = offset
            return self.read()
        self.close()
        return None

    def __iter__(self) -> Iterator[Frame]:
        if not self.is_open:
            self.open()
        while (frame := self.read()) is not None:
            yield frame

    def __enter__(self) -> VideoFileReader:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ImageSource:
    """A still image played as a camera at ``fps``: once, or forever with ``loop=True``.

    Time is ``seq / fps`` seconds.
    """

    def __init__(self, path: str | Path, camera_id: str, *, fps: float = 10.0,
                 loop: bool = False):
        self.path = Path(path)
        self.camera_id = camera_id
        self.description = str(path)
        self.fps: float | None = fps
        self.loop = loop
        self._image: np.ndarray | None = None
        self._seq = 0

    @property
    def is_open(self) -> bool:
        return self._image is not None

    def open(self) -> None:
        if not self.path.is_file():
            raise InputError(f"{self.description}: no such file")
        image = cv2.imread(str(self.path), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(f"{self.description}: not a readable image")
        self._image, self._seq = image, 0

    def read(self) -> Frame | None:
        if self._image is None or (self._seq > 0 and not self.loop):
            return None
        height, width = self._image.shape[:2]
        info = FrameInfo(self.camera_id, self._seq, self._seq / (self.fps or 10.0), width, height)
        self._seq += 1
        return Frame(self._image, info)

    def close(self) -> None:
        self._image = None


# --- live sources -------------------------------------------------------------------------------

class CameraSource:
    """A local camera by index (V4L2 on Linux). ``capture_time`` is the monotonic clock when
    ``read()`` returned. ``request_size`` asks the driver for a resolution (it may refuse)."""

    def __init__(self, index: int, camera_id: str, *, request_size: Size | None = None,
                 backend: int = cv2.CAP_ANY, clock: Clock = time.monotonic):
        self.index = index
        self.camera_id = camera_id
        self.description = f"camera {index} ({camera_id})"
        self.fps: float | None = None
        self.request_size = request_size
        self.backend = backend
        self.clock = clock
        self._cap: cv2.VideoCapture | None = None
        self._seq = 0

    @property
    def is_open(self) -> bool:
        return self._cap is not None

    def open(self) -> None:
        self.close()
        cap = cv2.VideoCapture(self.index, self.backend)
        if not cap.isOpened():
            cap.release()
            raise InputError(f"{self.description}: cannot open (no such device, busy, or no "
                             f"permission)")
        if self.request_size is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.request_size[0])
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.request_size[1])
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # fewer queued frames: newer frames, less lag
        fps = cap.get(cv2.CAP_PROP_FPS)
        self.fps = fps if math.isfinite(fps) and fps > 0 else None
        self._cap = cap

    def read(self) -> Frame | None:
        if self._cap is None:
            raise InputError(f"{self.description}: not open")
        ok, image = self._cap.read()
        if not ok or image is None:
            raise InputError(f"{self.description}: read failed (camera disconnected?)")
        return _stamped(image, self.camera_id, self._next_seq(), self.clock())

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq - 1

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
        self._cap = None


class StreamSource(CameraSource):
    """An RTSP/HTTP/... stream through OpenCV's FFmpeg backend, with open and read timeouts so a
    dead network camera raises instead of blocking. RTSP over TCP: set the environment variable
    ``OPENCV_FFMPEG_CAPTURE_OPTIONS=rtsp_transport;tcp`` before start."""

    def __init__(self, url: str, camera_id: str, *, open_timeout_s: float = 5.0,
                 read_timeout_s: float = 5.0, clock: Clock = time.monotonic):
        super().__init__(-1, camera_id, backend=cv2.CAP_FFMPEG, clock=clock)
        self.url = url
        self.description = f"{redact_url(url)} ({camera_id})"
        self.open_timeout_s = open_timeout_s
        self.read_timeout_s = read_timeout_s

    def open(self) -> None:
        self.close()
        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(self.open_timeout_s * 1000),
                  cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(self.read_timeout_s * 1000)]
        cap = cv2.VideoCapture(self.url, cv2.CAP_FFMPEG, params)
        if not cap.isOpened():
            cap.release()
            raise InputError(f"{self.description}: cannot open stream (unreachable, refused, "
                             f"or not a video)")
        fps = cap.get(cv2.CAP_PROP_FPS)
        self.fps = fps if math.isfinite(fps) and fps > 0 else None
        self._cap = cap

    def read(self) -> Frame | None:
        if self._cap is None:
            raise InputError(f"{self.description}: not open")
        ok, image = self._cap.read()
        if not ok or image is None:
            raise InputError(f"{self.description}: stream lost (read failed or timed out)")
        return _stamped(image, self.camera_id, self._next_seq(), self.clock())


def _stamped(image: np.ndarray, camera_id: str, seq: int, t: float) -> Frame:
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    return Frame(image, FrameInfo(camera_id, seq, t, image.shape[1], image.shape[0]))


# Scenes that ``synthetic:<name>`` can play.
SYNTHETIC_SCENES: dict[str, Callable[[], DemoScene]] = {"demo": DemoScene}


class SyntheticSource:
    """Plays a generated scene (default :class:`~monitor.scene.DemoScene`); time is
    ``seq / scene.fps`` seconds. ``loop=True`` plays it forever. ``last_truth`` is the ground
    truth of the frame read last (for tests and demos)."""

    def __init__(self, scene: DemoScene, camera_id: str, *, loop: bool = False,
                 name: str = "demo"):
        self.scene = scene
        self.camera_id = camera_id
        self.description = f"synthetic:{name} ({camera_id})"
        self.fps: float | None = scene.fps
        self.loop = loop
        self.last_truth: FrameTruth | None = None
        self._frames: Iterator[tuple[np.ndarray, FrameTruth]] | None = None
        self._seq = 0

    @property
    def is_open(self) -> bool:
        return self._frames is not None

    def open(self) -> None:
        self._frames, self._seq = self.scene.frames(), 0

    def read(self) -> Frame | None:
        if self._frames is None:
            return None
        item = next(self._frames, None)
        if item is None and self.loop and self._seq > 0:
            self._frames = self.scene.frames()
            item = next(self._frames, None)
        if item is None:
            self._frames = None
            return None
        image, self.last_truth = item
        info = FrameInfo(self.camera_id, self._seq, self._seq / self.scene.fps, image.shape[1],
                         image.shape[0])
        self._seq += 1
        return Frame(image, info)

    def close(self) -> None:
        self._frames = None


class PacedSource:
    """Plays a file or synthetic source in real time: ``read()`` waits until the frame's video
    time (divided by ``speed``) has passed since the first frame. A jump back in video time
    (loop, reopen) starts the schedule again. Late frames are returned at once (no catch-up
    burst beyond what is already late). ``stop`` interrupts a wait."""

    def __init__(self, source: FrameSource, *, speed: float = 1.0, clock: Clock = time.monotonic,
                 stop: threading.Event | None = None,
                 sleep: Callable[[float], object] | None = None):
        if speed <= 0:
            raise ValueError(f"PacedSource: speed must be > 0, got {speed}")
        self.source = source
        self.camera_id = source.camera_id
        self.description = source.description
        self.fps = source.fps
        self.speed = speed
        self.clock = clock
        self._sleep = sleep or (stop or threading.Event()).wait
        self._anchor: tuple[float, float] | None = None  # (clock, video time) of the schedule
        self._last_video_time: float | None = None

    @property
    def is_open(self) -> bool:
        return self.source.is_open

    def open(self) -> None:
        self.source.open()
        self._anchor, self._last_video_time = None, None

    def read(self) -> Frame | None:
        frame = self.source.read()
        if frame is None:
            return None
        t = frame.info.capture_time
        if self._anchor is None or self._last_video_time is None or t < self._last_video_time:
            self._anchor = (self.clock(), t)
        self._last_video_time = t
        due = self._anchor[0] + (t - self._anchor[1]) / self.speed
        delay = due - self.clock()
        if delay > 0:
            self._sleep(delay)
        return frame

    def close(self) -> None:
        self.source.close()


# --- registry -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class SourceOptions:
    """Options :func:`open_source` passes to the source constructors."""

    loop: bool = False
    image_fps: float = 10.0
    open_timeout_s: float = 5.0
    read_timeout_s: float = 5.0
    request_size: Size | None = None  # cameras only
    clock: Clock = time.monotonic


def _make_camera(spec: str | int, camera_id: str, o: SourceOptions) -> FrameSource:
    return CameraSource(int(spec), camera_id, request_size=o.request_size, clock=o.clock)


def _make_url(spec: str | int, camera_id: str, o: SourceOptions) -> FrameSource:
    return StreamSource(str(spec), camera_id, open_timeout_s=o.open_timeout_s,
                        read_timeout_s=o.read_timeout_s, clock=o.clock)


def _make_file(spec: str | int, camera_id: str, o: SourceOptions) -> FrameSource:
    return VideoFileReader(str(spec), camera_id, loop=o.loop)


def _make_image(spec: str | int, camera_id: str, o: SourceOptions) -> FrameSource:
    return ImageSource(str(spec), camera_id, fps=o.image_fps, loop=o.loop)


def _make_synthetic(spec: str | int, camera_id: str, o: SourceOptions) -> FrameSource:
    name = str(spec).split(":", 1)[1]
    if name not in SYNTHETIC_SCENES:
        raise InputError(f"{spec}: unknown synthetic scene {name!r} (known: "
                         f"{', '.join(sorted(SYNTHETIC_SCENES))})")
    return SyntheticSource(SYNTHETIC_SCENES[name](), camera_id, loop=o.loop, name=name)


# kind -> constructor; ``source_kind`` picks the kind from the spec.
SOURCE_KINDS: dict[str, Callable[[str | int, str, SourceOptions], FrameSource]] = {
    "camera": _make_camera,
    "url": _make_url,
    "file": _make_file,
    "image": _make_image,
    "synthetic": _make_synthetic,
}
PACEABLE_KINDS = frozenset({"file", "image", "synthetic"})  # have their own time to play at


def open_source(spec: str | int, camera_id: str, *, realtime: bool = True,
                options: SourceOptions | None = None,
                stop: threading.Event | None = None) -> FrameSource:
    """Make the source for ``spec`` and open it (so a bad spec fails at start-up).

    ``spec``: a camera index (``0`` or ``"0"``), a video or image path, an ``rtsp://`` /
    ``http(s)://`` URL, or ``synthetic:demo``. Files, images and synthetic scenes are played at
    their own frame rate when ``realtime`` (the live service); cameras and streams set their own
    pace. Raises InputError with a one-line message.
    """
    options = options or SourceOptions()
    kind = source_kind(spec)
    source = SOURCE_KINDS[kind](spec, camera_id, options)
    source.open()
    if realtime and kind in PACEABLE_KINDS:
        return PacedSource(source, clock=options.clock, stop=stop)
    return source


# --- grabber ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class GrabberStatus:
    """A snapshot of a grabber for health checks and metrics. Times on the grabber's clock."""

    camera_id: str
    connected: bool  # True while reads succeed; False after a loss until frames flow again
    ended: bool  # the source reached its regular end (a file without loop)
    grabbed: int  # frames read from the source
    dropped: int  # frames replaced by a newer one before anyone took them
    losses: int  # loss episodes (read or open error, wrong frame size), each counted once
    reconnects: int  # times frames flowed again after a loss
    last_frame_time: float | None  # clock at the newest grab, None before the first
    last_error: str  # one line; "" if none yet


class LatestFrameGrabber:
    """Reads a source in a thread and always hands out the newest frame.

    Each frame is re-stamped: ``seq`` counts grabbed frames of this camera (gaps = dropped
    frames) and ``capture_time`` is ``clock()`` right after the source returned it (monotonic
    seconds unless a test injects another clock). A frame not taken before the next arrives is
    dropped and counted. After a read failure, an open failure or a frame of the wrong size, the
    grabber closes the source, marks itself disconnected with the error text, and reopens after
    ``backoff.delay(attempt)`` seconds (real time, interruptible by ``stop``).

    The thread ends when ``stop`` (shared with the rest of the service) is set; ``stop()`` sets it
    and joins with a bounded timeout. A read that blocks inside the driver cannot be interrupted:
    the thread is a daemon, ``join`` reports whether it ended.
    """

    def __init__(self, source: FrameSource, *, stop: threading.Event | None = None,
                 expected_size: Size | None = None, clock: Clock = time.monotonic,
                 backoff: Backoff | None = None):
        self.source = source
        self.camera_id = source.camera_id
        self.expected_size = expected_size
        self.clock = clock
        self.backoff = backoff or Backoff()
        self.stop_event = stop or threading.Event()
        self._cond = threading.Condition()
        self._latest: Frame | None = None
        self._taken = True
        self._grabbed = 0
        self._dropped = 0
        self._losses = 0
        self._reconnects = 0
        self._connected = False
        self._ended = False
        self._finished = False
        self._last_frame_time: float | None = None
        self._last_error = ""
        self._thread = threading.Thread(target=self._run, name=f"grab-{self.camera_id}",
                                        daemon=True)

    # lifecycle
    def start(self) -> LatestFrameGrabber:
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> bool:
        """Set the stop event (shared: it stops everything that waits on it) and join."""
        self.stop_event.set()
        return self.join(timeout)

    def join(self, timeout: float = 2.0) -> bool:
        """Wait at most ``timeout`` seconds for the thread; True if it ended."""
        if self._thread.is_alive():
            self._thread.join(timeout)
        return not self._thread.is_alive()

    def __enter__(self) -> LatestFrameGrabber:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # consumer side
    def get(self, timeout: float | None = None) -> Frame | None:
        """The newest frame not handed out yet; waits up to ``timeout`` seconds for one.
        None on timeout, after stop, or at the end of the stream."""
        with self._cond:
            self._cond.wait_for(lambda: not self._taken or self._finished
                                or self.stop_event.is_set(), timeout)
            if self._taken:
                return None
            self._taken = True
            return self._latest

    def status(self) -> GrabberStatus:
        with self._cond:
            return GrabberStatus(self.camera_id, self._connected, self._ended, self._grabbed,
                                 self._dropped, self._losses, self._reconnects,
                                 self._last_frame_time, self._last_error)

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def dropped(self) -> int:
        return self._dropped

    @property
    def grabbed(self) -> int:
        return self._grabbed

    @property
    def reconnects(self) -> int:
        return self._reconnects

    @property
    def losses(self) -> int:
        return self._losses

    @property
    def ended(self) -> bool:
        return self._ended

    @property
    def last_frame_time(self) -> float | None:
        return self._last_frame_time

    @property
    def last_error(self) -> str:
        return self._last_error

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    # thread
    def _run(self) -> None:
        attempt = 0  # reconnect attempts since the last loss
        lost = False
        try:
            while not self.stop_event.is_set():
                try:
                    if not self.source.is_open:
                        self.source.open()
                    frame = self.source.read()
                    grabbed_at = self.clock()  # as close to the grab as Python gets
                    if frame is None:
                        self._finish_stream()
                        return
                    height, width = frame.image.shape[:2]
                    check_frame_size(width, height, self.expected_size, self.source.description)
                except Exception as exc:  # any failure is a loss: recorded, never fatal here
                    if self.stop_event.is_set():
                        break  # shutting down: a read cut short is no camera loss
                    new_loss = not lost
                    if new_loss:
                        lost, attempt = True, 0
                    self._on_loss(exc, new_loss)
                    self.stop_event.wait(self.backoff.delay(attempt))
                    attempt += 1
                    continue
                if lost:
                    lost = False
                    with self._cond:
                        self._reconnects += 1
                self._publish(frame, grabbed_at)
        finally:
            self._close_source()
            with self._cond:
                self._connected = False
                self._finished = True
                self._cond.notify_all()

    def _publish(self, frame: Frame, t: float) -> None:
        height, width = frame.image.shape[:2]
        with self._cond:
            info = FrameInfo(self.camera_id, self._grabbed, t, width, height)
            if not self._taken:
                self._dropped += 1
            self._latest, self._taken = Frame(frame.image, info), False
            self._grabbed += 1
            self._last_frame_time = t
            self._connected = True
            self._cond.notify_all()

    def _on_loss(self, exc: Exception, new_loss: bool) -> None:
        text = str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
        with self._cond:
            self._losses += int(new_loss)
            self._connected = False
            self._last_error = one_line(text)
        self._close_source()

    def _finish_stream(self) -> None:
        with self._cond:
            self._ended = True
            self._connected = False
            self._last_error = f"{self.source.description}: end of stream"

    def _close_source(self) -> None:
        try:
            self.source.close()
        except Exception as exc:  # closing a broken device may fail too; keep the first error
            with self._cond:
                self._last_error = self._last_error or one_line(f"close failed: {exc}")

