"""The driver's own fault decisions at their exact limits (monitor/driver.py): ``frame_late``
judges the frame's age when its step ends against ``max_frame_age`` (at the limit: not late),
and a loop gap of exactly ``stall_after_s`` is no stall. Mutation testing
(benchmarks/mutation.py, target ``driver``) found what these pin down. Real detector, the
demo cell; the clock is the driver's injected one (binary-exact times)."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from monitor.config import demo_cell_path
from monitor.driver import LATE_FAULT, STALL_FAULT, Driver, Step, StepInputs, settle_heap
from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig, ResetRequest
from monitor.scene import DemoScene
from monitor.types import Fault
from monitor.zones import load_cell
from tests.test_driver import Clock, FreezingClock, Recorder, frame_at

LIMIT = 0.25  # max_frame_age, binary-exact
POLICY = PolicyConfig(restart_interlock="auto", max_frame_age=LIMIT)


@pytest.fixture(scope="module")
def image() -> np.ndarray:
    return next(iter(DemoScene().frames()))[0]


def late_faults(step: Step) -> list:
    return [f for f in step.result.faults if f.name == LATE_FAULT]


def second_step(detector, image, *, age_at_start: float, step_s: float) -> Step:
    """The second step of a live driver: its frame ``age_at_start`` old when the step starts,
    the step itself taking ``step_s`` (the clock jumps at the step's "done" reading)."""
    clock = FreezingClock(at=5, by=step_s)  # readings: start, done, end; then start, DONE
    driver = Driver(Pipeline(detector, "cam0", POLICY, load_cell(demo_cell_path())),
                    [Recorder()], stall_after_s=0.5, clock=clock)
    driver.step(frame_at(image, 0, clock.t), clock.t)
    clock.t += 0.0625
    return driver.step(frame_at(image, 1, clock.t - age_at_start), clock.t)


def test_a_frame_exactly_max_frame_age_old_when_its_step_ends_is_not_late(detector, image):
    step = second_step(detector, image, age_at_start=0.125, step_s=0.125)
    assert step.stalled_s is None and not late_faults(step), step.result.faults


def test_a_frame_just_over_max_frame_age_when_its_step_ends_is_late_from_its_camera(
        detector, image):
    step = second_step(detector, image, age_at_start=0.125, step_s=0.125 + 2**-10)
    late = late_faults(step)
    assert late, f"no {LATE_FAULT}: {step.result.faults}"
    assert late[0].stop is True and late[0].source == "cam0" and not late[0].latch
    assert late[0].reason == ("frame 0.25 s old when its step ended (> max_frame_age 0.25 s): "
                              "the step took 0.13 s")
    assert step.stalled_s is None and step.result.command.state == "STOP"


def test_a_loop_gap_of_exactly_stall_after_s_is_no_stall_and_just_over_is(detector, image):
    for gap, stalled in ((0.5, False), (0.5 + 2**-10, True)):
        clock = Clock()
        driver = Driver(Pipeline(detector, "cam0", POLICY, None), [Recorder()],
                        stall_after_s=0.5, clock=clock)
        driver.step(frame_at(image, 0, clock.t), clock.t)  # arms stall detection
        clock.t += gap
        step = driver.step(frame_at(image, 1, clock.t), clock.t)
        assert (step.stalled_s is not None) is stalled, gap
        assert (STALL_FAULT in {f.name for f in step.result.faults}) is stalled, gap
        assert driver.stalls == int(stalled)


def test_a_late_first_frame_arms_stall_detection(detector, image):
    """The first frame's step, decided anew as frame_late, still counts as the first frame:
    a gap after it is a stall (warm-up ends with the first frame, late or not)."""
    clock = FreezingClock(at=2, by=0.375)  # the first step's "done": 0.375 s, no stall
    driver = Driver(Pipeline(detector, "cam0", POLICY, None), [Recorder()],
                    stall_after_s=0.5, clock=clock)
    first = driver.step(frame_at(image, 0, clock.t), clock.t)
    assert late_faults(first) and first.stalled_s is None
    clock.t += 1.0
    assert driver.step(None, clock.t).stalled_s == pytest.approx(1.0)


def test_a_frame_grabbed_exactly_when_a_stall_was_seen_is_processed(detector, image):
    clock = Clock()
    driver = Driver(Pipeline(detector, "cam0", POLICY, None), [Recorder()],
                    stall_after_s=0.5, clock=clock)
    driver.step(frame_at(image, 0, clock.t), clock.t)
    clock.t += 2.0
    assert driver.step(None, clock.t).stalled_s is not None  # frames before now: dropped
    seen = clock.t
    clock.t += 0.0625
    assert driver.step(frame_at(image, 1, seen - 2**-10), clock.t).frame is None
    clock.t += 0.0625
    assert driver.step(frame_at(image, 2, seen), clock.t).frame is not None


# --- what a step hands on to the pipeline (mutation survivors of ``Driver.step``) -------------

FAULT = Fault("test_fault", "a fault handed in by the service", True, "cam0")


@pytest.mark.parametrize("tick", [False, True], ids=["frame", "tick"])
def test_a_fault_handed_in_reaches_the_decision_on_a_frame_and_on_a_tick(detector, image, tick):
    clock = Clock()
    driver = Driver(Pipeline(detector, "cam0", POLICY, load_cell(demo_cell_path())),
                    [Recorder()], stall_after_s=0.5, clock=clock)
    first = driver.step(frame_at(image, 0, clock.t), clock.t)
    assert "test_fault" not in fault_names(first)  # none handed in: none decided on
    clock.t += 0.0625
    frame = None if tick else frame_at(image, 1, clock.t)
    step = driver.step(frame, clock.t, StepInputs(extra_faults=(FAULT,)))
    assert step.result.command.state == "STOP"
    assert "test_fault" in fault_names(step), step.result.command.describe()


def fault_names(step: Step) -> set[str]:
    """The faults named in the step's command."""
    return {r.fault for r in step.result.command.reasons if r.code == "fault"}


@pytest.mark.parametrize("tick", [False, True], ids=["frame", "tick"])
def test_a_reset_handed_in_is_judged_on_a_frame_and_on_a_tick(detector, image, tick):
    clock = Clock()
    driver = Driver(Pipeline(detector, "cam0", POLICY, load_cell(demo_cell_path())),
                    [Recorder()], stall_after_s=0.5, clock=clock)
    first = driver.step(frame_at(image, 0, clock.t), clock.t)
    assert first.result.command.reset is None  # none asked: none judged
    clock.t += 0.0625
    frame = None if tick else frame_at(image, 1, clock.t)
    step = driver.step(frame, clock.t, StepInputs(reset=ResetRequest("op", clock.t,
                                                                     request_id="r-1")))
    outcome = step.result.command.reset
    assert outcome is not None and outcome.request_id == "r-1", step.result.command


class _Node:
    def __init__(self) -> None:
        self.me = self  # a cycle: only the collector frees it


def test_settle_heap_collects_garbage_first_then_freezes_what_lives():
    """The service's loop starts on a settled heap: start-up's garbage is freed (not frozen
    for good) and what lives is out of every later collection."""
    was = gc.isenabled()
    gc.disable()  # nothing collects the cycle below before settle_heap does
    try:
        garbage, kept = _Node(), _Node()
        dead = weakref.ref(garbage)
        del garbage
        frozen = settle_heap()
        assert dead() is None  # collected, not frozen
        assert frozen == gc.get_freeze_count() and frozen > 1000
        assert not any(o is kept for o in gc.get_objects())  # frozen: no collection scans it
    finally:
        gc.unfreeze()
        if was:
            gc.enable()
