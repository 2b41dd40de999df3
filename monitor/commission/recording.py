"""``monitor commission walk --record SECONDS``: record the walk from the config's camera into
``walk.mp4`` at a fixed frame rate, for the analysis of a recorded walk.

The video's clock must be the walk's: frame k of the file stands for ``k / fps`` seconds after
the first frame. A camera faster than ``fps`` has frames dropped; a slower one (or one that
stalls) has its newest frame repeated in the slots it missed. A frame that arrived in a slot
already filled, followed by an empty slot (arrival times jitter on a loaded host), fills that
slot: a distinct frame at most one slot late, not counted as a repeat.

The reading thread never encodes: frames go to a writer thread through a queue (a repeated slot
is the same array again, no copy), so a slow encoder on a loaded host (one H.264 write took
180 ms against a 100 ms slot in the trial) never makes the reader miss the camera's frames. The
queue is bounded by memory (``QUEUE_BYTES``) and the writer thread runs below the reader's
priority (a loaded host gives its CPU to taking the frames; the encoding catches up after);
should the encoder fall that far behind, the reader waits and the frames it then misses are
counted as repeated slots, as any other.

A recording whose share of repeated or missing slots exceeds ``MAX_MISSING`` is refused
(``check``) with the measured figures: a walk of 7 distinct frames in 400 tests nothing.
"""

from __future__ import annotations

import contextlib
import math
import os
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from monitor.errors import InputError
from monitor.replay.video import open_video_writer

MAX_MISSING = 0.05  # more than this share of the slots repeated or missing: refused
QUEUE_BYTES = 512 * 1024 * 1024  # frames waiting for the encoder, at most
ENCODER_NICE = 10  # the writer thread's niceness: the reader comes first
_DONE = object()


@dataclass(frozen=True)
class Recorded:
    path: Path
    frames: int  # slots written
    repeated: int  # slots filled with the previous frame (camera slower than fps, or stalled)
    dropped: int  # frames of the camera not written (camera faster than fps)
    codec: str
    slots: int = 0  # slots asked for (seconds x fps)
    camera_frames: int = 0  # frames read from the camera
    camera_fps: float = 0.0  # the rate they came at (capture clock)
    reader_waited_s: float = 0.0  # time the reader waited for the encoder (queue full)

    @property
    def missing(self) -> int:
        """Slots never written (the camera ended or was lost early) plus repeated ones."""
        return max(0, self.slots - self.frames) + self.repeated

    @property
    def distinct_share(self) -> float:
        return (self.frames - self.repeated) / self.slots if self.slots else 0.0

    def to_dict(self) -> dict:
        return {"slots": self.slots, "frames": self.frames, "repeated": self.repeated,
                "dropped": self.dropped, "missing": self.missing,
                "distinct_share": round(self.distinct_share, 4),
                "camera_frames": self.camera_frames, "camera_fps": round(self.camera_fps, 2),
                "reader_waited_s": round(self.reader_waited_s, 3), "codec": self.codec}


def record_walk(source, path: Path, seconds: float, fps: float,
                stop: threading.Event | None = None) -> Recorded:
    """Read ``source`` (a ``monitor.frames`` source, open) for ``seconds`` of its capture
    clock and write it to ``path`` at ``fps`` (the encoding on a thread of its own)."""
    stop = stop or threading.Event()
    slots = max(1, math.ceil(seconds * fps - 1e-9))
    encoder = _Encoder(path, fps)
    t0 = t_last = None
    written = repeated = dropped = read = 0
    last = None
    last_written = True  # False: ``last`` came in a slot already filled and is not written yet
    try:
        while written < slots and not stop.is_set() and encoder.error is None:
            frame = source.read()
            if frame is None:
                break  # the source ended or was lost: the walk is what was recorded
            read += 1
            t = frame.info.capture_time
            t0 = t if t0 is None else t0
            t_last = t
            slot = math.floor((t - t0) * fps + 1e-6)
            while written < min(slot, slots) and last is not None:
                encoder.put(last)
                written += 1
                if last_written:
                    repeated += 1
                else:
                    # the frame that came early (two in one slot: an HTTP camera's arrival
                    # times jitter on a loaded host) fills the empty slot after it, a distinct
                    # frame at most one slot late, where a repeat would show it all the same
                    dropped -= 1
                    last_written = True
            if slot == written and written < slots:
                encoder.put(frame.image)
                written += 1
                last_written = True
            else:
                dropped += 1
                last_written = False
            last = frame.image
    finally:
        codec = encoder.close()
    if encoder.error is not None:
        raise InputError(f"{path}: the video could not be written ({encoder.error})")
    if written == 0:
        raise InputError(f"{getattr(source, 'description', 'the camera')}: no frame could be "
                         "recorded")
    span = (t_last - t0) if t0 is not None and t_last is not None else 0.0
    camera_fps = (read - 1) / span if span > 0 else 0.0
    return Recorded(path, written, repeated, dropped, codec, slots, read, camera_fps,
                    encoder.waited_s)


def check(rec: Recorded, fps: float, max_missing: float = MAX_MISSING) -> None:
    """``InputError`` with the measured figures when too many slots are repeated or missing."""
    if rec.missing <= max_missing * rec.slots:
        return
    hint = (f"record at --fps {max(1, math.floor(rec.camera_fps * 0.9))} or less"
            if 0 < rec.camera_fps < fps else "check the camera's stream and the host's load")
    raise InputError(
        f"{rec.path}: recording refused: {rec.missing} of {rec.slots} slots repeated or missing "
        f"({100 * rec.missing / rec.slots:.0f} % > {100 * max_missing:.0f} %; "
        f"{rec.frames - rec.repeated} distinct frames); the camera gave {rec.camera_fps:.1f} fps "
        f"against --fps {fps:g} ({rec.camera_frames} frames read, the reader waited "
        f"{rec.reader_waited_s:.1f} s for the encoder): {hint}. The file is kept, not analysed")


class _Encoder:
    """The video writer on its own thread, fed through a queue bounded by memory."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path, self.fps = path, fps
        self.queue: queue.Queue | None = None
        self.thread: threading.Thread | None = None
        self.codec = ""
        self.error: str | None = None
        self.waited_s = 0.0

    def put(self, image) -> None:
        if self.queue is None:  # the first frame gives the size, and the queue's depth
            depth = max(8, QUEUE_BYTES // max(1, image.nbytes))
            self.queue = queue.Queue(maxsize=depth)
            self.thread = threading.Thread(target=self._run, args=(image.shape,),
                                           name="walk-encoder", daemon=True)
            self.thread.start()
        try:
            self.queue.put_nowait(image)
        except queue.Full:
            t = time.monotonic()
            self.queue.put(image)
            self.waited_s += time.monotonic() - t

    def _run(self, shape) -> None:
        # below the reader (Linux: a thread is a task of its own): on a loaded host the CPU
        # goes to taking the camera's frames first; the queue holds what waits for encoding
        with contextlib.suppress(OSError, AttributeError):
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), ENCODER_NICE)
        writer = None
        try:
            writer, self.codec = open_video_writer(self.path, self.fps, shape)
            while (image := self.queue.get()) is not _DONE:
                writer.write(image)
        except Exception as exc:  # the reader stops at its next frame and says so
            self.error = str(exc) or type(exc).__name__
            while self.queue.get() is not _DONE:  # let the reader finish its puts
                pass
        finally:
            if writer is not None:
                writer.release()

    def close(self) -> str:
        if self.queue is not None and self.thread is not None:
            self.queue.put(_DONE)
            self.thread.join()
        return self.codec
