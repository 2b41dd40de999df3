"""Video files read frame by frame on their own clock (replay), with a diagnosis of files
that cannot be opened (truncated, still being written, not a video)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from monitor.errors import InputError
from monitor.frames.base import (
    Frame,
    Size,
    TruncatedVideoError,
    check_frame_size,
    frame_time_s,
)
from monitor.types import FrameInfo


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
