"""Live and played sources (still images, cameras, RTSP/HTTP streams, the synthetic demo
scene, pacing at a file's own rate) and ``open_source``, which makes one from a spec string."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from monitor.errors import InputError
from monitor.frames.base import (
    Clock,
    Frame,
    FrameSource,
    Size,
    redact_url,
    source_kind,
)
from monitor.frames.video import VideoFileReader
from monitor.scene import DemoScene, FrameTruth
from monitor.types import FrameInfo


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

    read_failure = "read failed (camera disconnected?)"  # the loss as the user sees it

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
            raise InputError(f"{self.description}: {self.read_failure}")
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

    read_failure = "stream lost (read failed or timed out)"

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
