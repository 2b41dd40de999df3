"""The pre-event ring: one camera's last ``pre_s`` seconds as JPEG frames, within a byte budget.

Frames are kept compressed (a 720p frame is ~2.7 MB raw, ~0.1 MB as JPEG) together with the
step result they were decided with, so a clip drawn later shows what the monitor saw and
decided at that frame. Oldest frames go first: by age (``pre_s``) and by the byte budget (then
the window is shorter than ``pre_s``, and ``evicted_for_budget`` counts it).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class RingFrame:
    time: float  # capture time (the monitor's clock; the video's in replay)
    jpeg: bytes
    result: object  # the StepResult of that frame (alerts' snapshots stripped)

    def image(self) -> np.ndarray:
        image = cv2.imdecode(np.frombuffer(self.jpeg, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError("a ring frame is not a decodable JPEG")
        return image


class FrameRing:
    """Bounded by ``window_s`` of capture time and ``budget_bytes`` of JPEG data."""

    def __init__(self, window_s: float, budget_bytes: int) -> None:
        self.window_s = window_s
        self.budget_bytes = budget_bytes
        self.frames: deque[RingFrame] = deque()
        self.bytes = 0
        self.evicted_for_budget = 0

    def push(self, frame: RingFrame) -> None:
        self.frames.append(frame)
        self.bytes += len(frame.jpeg)
        while self.frames and self.frames[0].time < frame.time - self.window_s:
            self._pop()
        while self.bytes > self.budget_bytes and len(self.frames) > 1:
            self._pop()
            self.evicted_for_budget += 1

    def _pop(self) -> None:
        self.bytes -= len(self.frames.popleft().jpeg)

    def since(self, start: float) -> Iterator[RingFrame]:
        """The frames captured at or after ``start``, oldest first."""
        return (f for f in list(self.frames) if f.time >= start)

    def __len__(self) -> int:
        return len(self.frames)


def encode_jpeg(image: np.ndarray, quality: int) -> bytes:
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return data.tobytes()
