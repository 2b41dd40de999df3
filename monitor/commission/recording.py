"""``monitor commission walk --record SECONDS``: record the walk from the config's camera into
``walk.mp4`` at a fixed frame rate, for the analysis of a recorded walk.

The video's clock must be the walk's: frame k of the file stands for ``k / fps`` seconds after
the first frame. A camera faster than ``fps`` has frames dropped; a slower one (or one that
stalls) has its newest frame repeated in the slots it missed, and the count says so (the walk
then sees those frames as the monitor would: no newer image).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path

from monitor.errors import InputError
from monitor.replay.video import open_video_writer


@dataclass(frozen=True)
class Recorded:
    path: Path
    frames: int
    repeated: int  # slots filled with the previous frame (camera slower than fps)
    dropped: int  # frames of the camera not written (camera faster than fps)
    codec: str


def record_walk(source, path: Path, seconds: float, fps: float,
                stop: threading.Event | None = None) -> Recorded:
    """Read ``source`` (a ``monitor.frames`` source, open) for ``seconds`` of its capture
    clock and write it to ``path`` at ``fps``."""
    stop = stop or threading.Event()
    slots = max(1, math.ceil(seconds * fps - 1e-9))
    writer = codec = None
    t0 = None
    written = repeated = dropped = 0
    last = None
    try:
        while written < slots and not stop.is_set():
            frame = source.read()
            if frame is None:
                break  # the source ended or was lost: the walk is what was recorded
            t = frame.info.capture_time
            t0 = t if t0 is None else t0
            slot = math.floor((t - t0) * fps + 1e-6)
            if writer is None:
                writer, codec = open_video_writer(path, fps, frame.image.shape)
            while written < min(slot, slots) and last is not None:
                writer.write(last)
                written += 1
                repeated += 1
            if slot == written and written < slots:
                writer.write(frame.image)
                written += 1
            else:
                dropped += 1
            last = frame.image
    finally:
        if writer is not None:
            writer.release()
    if written == 0:
        raise InputError(f"{getattr(source, 'description', 'the camera')}: no frame could be "
                         "recorded")
    return Recorded(path, written, repeated, dropped, codec or "")
