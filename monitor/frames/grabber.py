"""The live service's grabber: a thread per camera that keeps only the newest frame,
stamps it on the monotonic clock, counts drops and reconnects after a loss."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from monitor.errors import InputError
from monitor.frames.base import (
    Backoff,
    Clock,
    Frame,
    FrameSource,
    Size,
    check_frame_size,
    one_line,
)
from monitor.types import FrameInfo


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
