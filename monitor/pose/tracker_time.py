"""Tracker time checked against receive time (issue 20).

The OTUS timestamps are the tracker's own clock and say nothing trustworthy on their own: in
milliseconds, a 50 ms speed window is one sample 2.5 "s" old and the tool reads as resting; a
forward jump makes the window span time that never passed; a step back leaves samples in the
history that the time cut never removes; a clock running slow stretches the window until it
aliases with the motion. So every pose's tracker time is compared with the monotonic time at
which the monitor received it:

* the offset (receive time - tracker time) is learned over ``learn_s`` of receive time: while
  learning, the offsets seen may spread by at most ``max_jump_s`` (a clock in milliseconds, or
  running at another rate, spreads by seconds);
* once learned, each pose's offset may differ from the estimate by at most ``max_jump_s``
  (a jump either way, or a pose delivered that late), and the estimate itself follows the
  poses by at most ``max_drift`` seconds per second (so small jumps in a row add up);
* any of these is a STOP fault ``pose_implausible`` (source ``pose``); the caller clears the
  speed history, and the offset is learned again: the fault holds until ``learn_s`` of poses
  agree with each other again.

Pure state, no I/O, no clock of its own: the caller passes the receive time.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated

from pydantic import Field

from monitor.schema import Float, section

if TYPE_CHECKING:
    from monitor.types import Fault

FAULT = "pose_implausible"


@section("tracker_clock")
class TrackerClockConfig:
    """How far the tracker's timestamps may stray from the monitor's receive times (seconds)."""

    # largest difference between a pose's tracker time and its receive time once the offset is
    # learned: a jump of the tracker's clock either way, or a pose delivered this late (keep it
    # near [policy] pose_timeout: a later pose is stale anyway)
    max_jump_s: Annotated[Float, Field(gt=0, le=1.0)] = 0.1
    # largest rate at which the tracker's clock may drift from the monitor's, s per s
    # (0.001 = 1 ms per second; quartz clocks drift ~0.0001)
    max_drift: Annotated[Float, Field(gt=0, le=0.01)] = 0.001
    # receive time over which the offset is learned at start, and again after a fault (the
    # fault holds that long)
    learn_s: Annotated[Float, Field(gt=0, le=10.0)] = 0.5


@dataclass
class TrackerClock:
    """Checks one pose stream's tracker times against receive times (not thread-safe; the
    ``PoseSubscriber`` calls it under its lock)."""

    config: TrackerClockConfig

    def __post_init__(self) -> None:
        self.offset_s: float | None = None  # learned receive - tracker time, None while learning
        self.fault: Fault | None = None  # in force until the offset is learned again
        self.faults = 0
        self._last_received: float | None = None
        self._learn_start: tuple[float, float] | None = None  # (received, tracker time)
        self._learn_lo = self._learn_hi = 0.0

    def check(self, tracker_time: float, received: float) -> Fault | None:
        """The fault in force after this pose (None: tracker time agrees with receive time).
        A pose that breaks the rules starts the learning again from itself."""
        offset = received - tracker_time
        step = 0.0 if self._last_received is None else max(0.0, received - self._last_received)
        self._last_received = received
        if self.offset_s is None:
            return self._learn(tracker_time, received, offset)
        error = offset - self.offset_s
        if abs(error) > self.config.max_jump_s:
            where = "ahead of" if error < 0 else "behind"
            return self._fail(f"tracker time is {abs(error):.3f} s {where} receive time "
                              f"(max_jump_s {self.config.max_jump_s:g})", tracker_time, received)
        # the estimate follows slowly: a clock drifting faster than max_drift runs away from it
        room = self.config.max_drift * step
        self.offset_s += max(-room, min(room, error))
        return None

    def _learn(self, tracker_time: float, received: float, offset: float) -> Fault | None:
        if self._learn_start is None:
            self._learn_start = (received, tracker_time)
            self._learn_lo = self._learn_hi = offset
            return self.fault
        self._learn_lo, self._learn_hi = min(self._learn_lo, offset), max(self._learn_hi, offset)
        if self._learn_hi - self._learn_lo > self.config.max_jump_s:
            r0, t0 = self._learn_start
            ran, passed = tracker_time - t0, received - r0
            units = "; timestamps not in seconds?" if abs(ran) > 100 * max(passed, 1e-3) \
                or abs(ran) < passed / 100 else ""
            return self._fail(f"tracker time ran {ran:.4g} s in {passed:.4g} s of receive "
                              f"time (max_jump_s {self.config.max_jump_s:g}{units})",
                              tracker_time, received)
        if received - self._learn_start[0] >= self.config.learn_s:
            # the least delayed pose is the best estimate: delivery only ever adds delay
            self.offset_s = self._learn_lo
            self.fault = None
        return self.fault

    def _fail(self, reason: str, tracker_time: float, received: float) -> Fault:
        from monitor.types import Fault  # types pulls numpy; the pose bridge stays light

        self.faults += 1
        self.fault = Fault(FAULT, reason, True, "pose")
        self.offset_s = None
        self._learn_start = (received, tracker_time)
        self._learn_lo = self._learn_hi = received - tracker_time
        return self.fault
