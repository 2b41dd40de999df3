"""The one loop around ``Pipeline``, for the live service and for replay.

A *feed* hands in the next frame (or None: nothing new) and the time to decide at, plus the
outside inputs of that moment (resets, tool pose, camera faults). The ``Driver`` turns each into
one ``Pipeline.process`` or ``Pipeline.tick`` step, adds what both modes need (reset alerts, the
detector self-test, "a reset is possible now", stall detection) and hands every step to its
*sinks* (bus, logs, metrics, events.jsonl, annotated video) in order: the safety sink first.

Live and replay differ only in their feed and sinks: live frames come from grabbers on the
monotonic clock and the feed ticks at least every ``service.tick_s``; a replay feed walks the
video's own timestamps and inserts ticks every ``tick_s`` of video time between two frames, so
a gap in the video's timestamps longer than ``policy.frame_timeout`` gives ``frame_timeout``
in replay exactly as a silent camera does live.

Stall detection (live only): the driver measures its own loop on the monotonic clock. A gap
longer than ``stall_after_s`` (the policy's ``frame_timeout``) between two steps, or inside one
step, means the process was frozen (SIGSTOP, a paused VM, a long GC): the monitor was blind.
That step's result is discarded, frames grabbed before the gap are dropped, and a
``monitor_stalled`` fault with ``latch=True`` goes to the policy: STOP, latched, a critical
alert and a log line. Replay never measures wall time, so its events stay deterministic.
"""

from __future__ import annotations

import dataclasses
import gc
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from monitor.cases.muting import MuteRequest
from monitor.frames import Frame
from monitor.pipeline import Pipeline, StepResult
from monitor.policy import ResetRequest
from monitor.types import Fault
from monitor.wire.object_accepts import ObjectAccept


def settle_heap() -> int:
    """Collect once, then freeze every object alive now out of all later collections; returns
    how many are frozen.

    The service calls it once before its loop: what start-up built (modules, the model session,
    zones, config: about 108k objects for the default config) lives as long as the service.
    Left in the collector's generations, each full collection scans them again: about 90 ms of
    the decision thread at a moment nobody chose, straight into the worst-case reaction time.
    """
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


STALL_FAULT = "monitor_stalled"
LATE_FAULT = "frame_late"  # a step so slow that its frame was too old once decided


@dataclass(frozen=True)
class StepInputs:
    """What the outside world hands in at one step besides the frame."""

    reset: ResetRequest | None = None
    extra_faults: tuple[Fault, ...] = ()
    tool_pose: object = None
    tool_speed_mps: float | None = None
    pose_time: float | None = None
    mutes: tuple[MuteRequest, ...] = ()  # verified mute requests (judged by the pipeline)
    # verified acceptances of objects since commissioning (judged by the pipeline)
    accepts: tuple[ObjectAccept, ...] = ()
    # zone set selections and refused selection requests (monitor/cases/), oldest first
    case_events: tuple = ()


@dataclass(frozen=True)
class Step:
    """One step as the sinks see it."""

    result: StepResult
    frame: Frame | None  # the frame processed; None for a timer tick
    index: int  # seq of the newest processed frame (-1 before the first)
    stalled_s: float | None = None  # loop gap when this step reports a stall
    reset_possible: bool = False  # a reset became possible at this step (it was not before)
    decided_at: float | None = None  # the driver's clock at the decision (live only)


class Sink(Protocol):
    """Something fed with every step: bus, log, metrics, events file, annotated video."""

    def on_step(self, step: Step) -> None: ...

    def close(self) -> None: ...


class Feed(Protocol):
    """Where frames and time come from. ``next()`` returns ``(frame or None, now)`` or None
    when the feed has ended; ``inputs(now)`` the resets, pose and faults of that moment.
    ``idle=True``: a check is due, so a live feed returns a tick at once when no frame is
    waiting (the check then runs in the gap before the next frame, not in front of it)."""

    def next(self, idle: bool = False) -> tuple[Frame | None, float] | None: ...

    def inputs(self, now: float) -> StepInputs: ...


def has_protective_zone(cell) -> bool:
    """True when the cell has an enabled protective zone (the only thing that STOPs for a
    person). Uses ``Cell.has_protective_zone`` where the zone package provides it."""
    if cell is None:
        return False
    value = getattr(cell, "has_protective_zone", None)
    if value is not None:
        return bool(value() if callable(value) else value)
    return any(z.kind == "protective" and getattr(z, "enabled", True) for z in cell.zones)


def protective_warning(cell) -> str | None:
    """The line to state at start and in status when no person can cause a STOP."""
    if has_protective_zone(cell):
        return None
    what = "no zone file" if cell is None else f"zone file {cell.label} has no enabled " \
        "protective zone"
    return f"{what}: persons cannot cause STOP (allowed by allow_no_protective)"


def require_protective_zone(cell, allowed: bool, where: str) -> None:
    """Refuse a cell where no person can ever cause a STOP, unless explicitly allowed."""
    if allowed or has_protective_zone(cell):
        return
    from monitor.errors import ConfigError

    what = "no zone file is given" if cell is None else \
        f"{where} has no enabled protective zone"
    raise ConfigError(f"{what}: persons could never cause STOP; add a protective zone, or set "
                      f"[zones] allow_no_protective = true if that is meant")


def reset_possible(command) -> bool | None:
    """Whether the policy says a reset would be accepted now (None: the policy does not say)."""
    value = getattr(command, "reset_possible", None)
    return None if value is None else bool(value)


class Driver:
    """Frames and ticks in, steps out to the sinks.

    ``stall_after_s`` enables stall detection on ``clock`` (None: off, as in replay).
    ``self_test_period_s``: the detector's ``self_test()`` (when it has one) runs at the first
    step and then this often (seconds of ``now``); its fault holds until a test passes.
    """

    def __init__(self, pipeline: Pipeline, sinks: Sequence[Sink] = (), *,
                 stall_after_s: float | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 self_test_period_s: float | None = None, inplace=None) -> None:
        self.pipeline = pipeline
        self.sinks = list(sinks)
        self.stall_after_s = stall_after_s
        self.clock = clock
        self.self_test = getattr(pipeline.detector, "self_test", None)
        self.self_test_period_s = self_test_period_s
        self._next_self_test: float | None = None
        # the in-place check (monitor/detector/inplace.py): on timer ticks, on the newest frame
        self.inplace = inplace
        self._newest: dict[str, Frame] = {}
        self._self_test_fault: Fault | None = None
        self._last_end: float | None = None  # clock at the end of the previous step
        self._armed = False  # stall detection starts after the first frame (warm-up excluded)
        self._discard_before: float | None = None
        self._index = -1
        self._last_now: float | None = None  # the newest step's time (for checks_due)
        self._reset_possible = False
        self.stalls = 0
        self.steps = 0

    def run(self, feed: Feed, stop: threading.Event, batch: bool = False) -> None:
        """Step until the feed ends or ``stop`` is set. ``batch``: take every camera's frame
        that is ready together from ``feed.next_batch()`` and detect them as one batch."""
        while not stop.is_set():
            idle = self.checks_due(self._last_now)
            item = (feed.next_batch(idle=idle) if batch  # type: ignore[attr-defined]
                    else feed.next(idle=idle))
            if item is None or stop.is_set():
                break
            frames, now = item
            if not batch:
                self.step(frames, now, feed.inputs(now))
            elif len(frames) <= 1:
                self.step(frames[0] if frames else None, now, feed.inputs(now))
            else:
                self.step_batch(frames, now, feed.inputs(now))

    def step_batch(self, frames: Sequence[Frame], now: float,
                   inputs: StepInputs = StepInputs()) -> list[Step]:
        """Frames of several cameras ready together: one detector batch, one Step per frame
        (each a decision with every camera's newest answer), stall detection as ``step``."""
        inputs = self._judge_mutes(inputs, now)
        start = self.clock() if self.stall_after_s is not None else 0.0
        if inputs.case_events:
            self.pipeline.take_case_events(inputs.case_events, now)
            inputs = dataclasses.replace(inputs, case_events=())  # taken once, even on a stall
        if self._stall_gap(start, self._last_end) is not None:
            return [self._stalled(start - self._last_end, inputs)]
        if self._discard_before is not None:
            frames = [f for f in frames if f.info.capture_time >= self._discard_before]
        if len(frames) <= 1:
            return [self.step(frames[0] if frames else None, now, inputs)]
        for f in frames[1:]:
            self._newest[f.info.camera_id] = f
        faults = (inputs.extra_faults + self._run_self_test(now, True)
                  + self._run_inplace(frames[0], now))
        self._last_now = now
        results = self.pipeline.process_batch(
            [(f.image, f.info) for f in frames], now, tool_pose=inputs.tool_pose,
            tool_speed_mps=inputs.tool_speed_mps, pose_time=inputs.pose_time,
            reset=inputs.reset, extra_faults=faults)
        if self.stall_after_s is not None:
            done = self.clock()
            if self._stall_gap(done, start) is not None:  # frozen while deciding: stale results
                steps = []
                for frame, result in zip(frames, results, strict=True):
                    self._index = frame.info.seq
                    steps.append(self._stalled(done - start, inputs, result, frame))
                return steps
        self._armed = True
        steps = []
        for frame, result in zip(frames, results, strict=True):
            self._index = frame.info.seq
            late = self._late_fault(frame, done, start) if self.stall_after_s is not None \
                else None
            steps.append(self._redecided(late, inputs, result, frame) if late
                         else self._emit(result, frame))
        return steps

    def step(self, frame: Frame | None, now: float, inputs: StepInputs = StepInputs()
             ) -> Step:
        """One pipeline step (a frame, or a tick when ``frame`` is None), fed to the sinks."""
        inputs = self._judge_mutes(inputs, now)
        start = self.clock() if self.stall_after_s is not None else 0.0
        if inputs.case_events:
            self.pipeline.take_case_events(inputs.case_events, now)
            inputs = dataclasses.replace(inputs, case_events=())  # taken once
        if self._stall_gap(start, self._last_end) is not None:
            return self._stalled(start - self._last_end, inputs)
        if frame is not None and self._discard_before is not None \
                and frame.info.capture_time < self._discard_before:
            frame = None  # grabbed before the monitor froze: it shows a past cell
        faults = (inputs.extra_faults + self._run_self_test(now, frame is not None)
                  + self._run_inplace(frame, now))
        self._last_now = now
        if frame is not None:
            result = self.pipeline.process(
                frame.image, frame.info, now, tool_pose=inputs.tool_pose,
                tool_speed_mps=inputs.tool_speed_mps, pose_time=inputs.pose_time,
                reset=inputs.reset, extra_faults=faults)
            self._index = frame.info.seq
        else:
            result = self.pipeline.tick(now, pose_time=inputs.pose_time, reset=inputs.reset,
                                        extra_faults=faults)
        if self.stall_after_s is not None:
            done = self.clock()
            if self._stall_gap(done, start) is not None:  # frozen while deciding: stale result
                return self._stalled(done - start, inputs, result if frame else None, frame)
            if frame is not None and (late := self._late_fault(frame, done, start)):
                self._armed = True
                return self._redecided(late, inputs, result, frame)
        if frame is not None:
            self._armed = True
        return self._emit(result, frame)

    def _judge_mutes(self, inputs: StepInputs, now: float) -> StepInputs:
        """Mute requests and acceptances of objects are judged before the step's decision,
        even a stalled one (their outcomes ride on its result; the bus answers them)."""
        if inputs.accepts:  # the same for acceptances of objects since commissioning
            self.pipeline.accept_objects(inputs.accepts, now)
            inputs = dataclasses.replace(inputs, accepts=())
        if not inputs.mutes:
            return inputs
        self.pipeline.request_mutes(inputs.mutes, now)
        return dataclasses.replace(inputs, mutes=())

    def _stall_gap(self, now: float, before: float | None) -> float | None:
        if self.stall_after_s is None or not self._armed or before is None:
            return None
        gap = now - before
        return gap if gap > self.stall_after_s else None

    def _late_fault(self, frame: Frame, done: float, start: float) -> Fault | None:
        """The policy judged the frame's age at the step's start; a step that took long (a
        model slow on some frames only) would hand on a decision about a cell older than
        ``max_frame_age``. Such a step is decided anew, now, as a STOP that clears slowly."""
        limit = self.pipeline.policy.max_frame_age
        age = done - frame.info.capture_time
        if not age > limit:  # NaN capture times are the policy's (frame_stale)
            return None
        return Fault(LATE_FAULT, f"frame {age:.2f} s old when its step ended (> max_frame_age "
                     f"{limit:g} s): the step took {done - start:.2f} s", True,
                     frame.info.camera_id)

    def _redecided(self, fault: Fault, inputs: StepInputs, processed: StepResult,
                   frame: Frame) -> Step:
        """A late step's command decided anew, now, with ``fault`` (its detections kept)."""
        result = self.pipeline.tick(self.clock(), pose_time=inputs.pose_time,
                                    extra_faults=(*inputs.extra_faults, fault))
        return self._emit(self._with_detections(result, processed), frame)

    @staticmethod
    def _with_detections(result: StepResult, processed: StepResult) -> StepResult:
        return dataclasses.replace(
            result, frame=processed.frame, persons=processed.persons,
            zone_report=processed.zone_report, health=processed.health,
            alerts=(*processed.alerts, *result.alerts), stage_ms=processed.stage_ms,
            mute_outcomes=(*processed.mute_outcomes, *result.mute_outcomes),
            accept_outcomes=(*processed.accept_outcomes, *result.accept_outcomes))

    def _stalled(self, gap: float, inputs: StepInputs, processed: StepResult | None = None,
                 frame: Frame | None = None) -> Step:
        """The command of a stalled step is decided anew, now, with the stall fault. A frame
        processed during the stall keeps its detections (they are real, only late): the
        sinks publish them, but never the command decided before the gap."""
        now = self.clock()
        self._discard_before = now
        self.stalls += 1
        fault = Fault(STALL_FAULT, f"monitor loop stalled for {gap:.2f} s (> {self.stall_after_s}"
                      f" s): process frozen, machine paused or overloaded; frames before "
                      f"the gap discarded", True, "monitor", latch=True)
        # a reset not yet handed to the pipeline is judged now (and refused: the stall holds)
        reset = inputs.reset if processed is None else None
        result = self.pipeline.tick(now, pose_time=inputs.pose_time, reset=reset,
                                    extra_faults=(*inputs.extra_faults, fault))
        if processed is not None:
            result = self._with_detections(result, processed)
        return self._emit(result, frame if processed is not None else None, stalled_s=gap)

    def checks_due(self, now: float | None) -> bool:
        """The self-test or a camera's in-place check is due (each is one more inference):
        the loop asks the feed for a tick while no frame waits, so it runs in the gap."""
        if now is None:
            return False
        if self.self_test is not None and self._next_self_test is not None \
                and now >= self._next_self_test:
            return True
        return self.inplace is not None and any(self.inplace.due(c, now) for c in self._newest)

    def _run_self_test(self, now: float, frame_step: bool) -> tuple[Fault, ...]:
        """At the first step, then on a timer tick once due; on a frame step only when a whole
        period overdue (a camera so fast the loop never idles): a frame never waits for it
        while the loop has a gap to run it in."""
        if self.self_test is None:
            return ()
        period = self.self_test_period_s or 0.0  # 0 or None: only at start (next is inf)
        due = self._next_self_test is None or now >= self._next_self_test
        overdue = self._next_self_test is None or now >= self._next_self_test + period
        if (due and not frame_step) or overdue:
            try:
                self._self_test_fault = self.self_test()
            except Exception as exc:  # a self-test that cannot run is a failed one
                self._self_test_fault = Fault("detector_self_test", f"self-test raised {exc}",
                                              True, "detector")
            self._next_self_test = now + period if period > 0 else float("inf")
        return (self._self_test_fault,) if self._self_test_fault is not None else ()

    def _run_inplace(self, frame: Frame | None, now: float) -> tuple[Fault, ...]:
        """The in-place check runs on a timer tick (no frame waiting), on each camera's newest
        frame; on a frame step only when a whole period overdue (a feed that never ticks)."""
        check = self.inplace
        if check is None:
            return ()
        if frame is not None:
            self._newest[frame.info.camera_id] = frame
        for cid, newest in self._newest.items():
            overdue = check.due(cid, now - check.period_s)
            if check.due(cid, now) and (frame is None or overdue):
                check.check(cid, newest.image, now)
        return tuple(check.faults.values())

    def _emit(self, result: StepResult, frame: Frame | None,
              stalled_s: float | None = None) -> Step:
        if result.command.reset is not None:
            from monitor.wire.alerts import RESET_SOURCE, reset_alert

            # the operator's act, not a camera's finding (the operator is in the details)
            alert = reset_alert(result.command.reset, RESET_SOURCE, result.now)
            result = dataclasses.replace(result, alerts=(*result.alerts, alert))
        possible = bool(reset_possible(result.command))
        became_possible = possible and not self._reset_possible
        self._reset_possible = possible
        decided_at = None
        if self.stall_after_s is not None:
            # the loop's gap is measured from the decision, before the sinks: a freeze while
            # publishing (a large share of a step) is then seen by the next step as a stall,
            # instead of hiding between the decision and a clock read after the sinks
            decided_at = self._last_end = self.clock()
        step = Step(result, frame, self._index, stalled_s, became_possible, decided_at)
        for sink in self.sinks:
            sink.on_step(step)
        self.steps += 1
        return step

    def close(self) -> None:
        """Close the sinks in reverse order (each one's failure does not skip the others)."""
        errors = []
        for sink in reversed(self.sinks):
            try:
                sink.close()
            except Exception as exc:  # keep closing: the other outputs must still be finished
                errors.append(exc)
        if errors:
            raise errors[0]
