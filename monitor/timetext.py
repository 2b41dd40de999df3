"""Times for operators: the policy and the tracker keep times as numbers on their own clock
(monotonic live, the video's clock in replay); the edges turn them into text an operator can
read with one of these (``TimeText``: a time on that clock -> text after "at")."""

from __future__ import annotations

import time
from collections.abc import Callable
from datetime import datetime

TimeText = Callable[[float], str]


def seconds(t: float) -> str:
    """The clock's own seconds (tests, and anything without a better clock)."""
    return f"{t:.1f} s"


def video_time(t: float) -> str:
    """Replay: seconds of the video, where the operator finds the moment in annotated.mp4."""
    return f"{t:.1f} s of the video"


def wall_clock(monotonic: Callable[[], float] = time.monotonic,
               wall: Callable[[], float] = time.time) -> TimeText:
    """Live: a monotonic time as local wall-clock time (``14:03:12``), with how long ago it
    was when that is a minute or more (an operator reading the log later needs the time, one
    reading it now the age)."""

    def text(t: float) -> str:
        ago = monotonic() - t
        stamp = datetime.fromtimestamp(wall() - ago).strftime("%H:%M:%S")
        if ago >= 60.0:
            return f"{stamp} ({_age(ago)} ago)"
        return stamp

    return text


def wall_iso(monotonic: Callable[[], float] = time.monotonic,
              wall: Callable[[], float] = time.time) -> TimeText:
    """Live records read later (incidents, their clips): a monotonic time as the local date and
    time, ISO 8601 to the second (``2026-11-28 14:03:12``), the clock the service's log uses."""

    def text(t: float) -> str:
        return datetime.fromtimestamp(wall() - (monotonic() - t)).isoformat(
            sep=" ", timespec="seconds")

    return text


def _age(s: float) -> str:
    if s < 3600:
        return f"{int(s // 60)} min"
    return f"{s / 3600:.1f} h"
