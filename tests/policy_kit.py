"""Small factories for the policy tests: inputs, frames, resets, timelines and random input
sequences (hypothesis), shared by tests/test_policy*.py and tests/test_describe.py."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest
from hypothesis import strategies as st

from monitor.policy import (
    PolicyConfig,
    PolicyInputs,
    ResetRequest,
    initial_state,
    step,
)
from monitor.types import Fault, ZoneHit, ZoneReport

AUTO = PolicyConfig(restart_interlock="auto")


MANUAL = PolicyConfig()


def prot(zone: str = "Z1", person: int = 0, distance: float | None = 0.0) -> ZoneHit:
    return ZoneHit(zone, "protective", person, 0.0, distance)


def warn(zone: str = "W1", scale: float = 0.5, person: int = 0) -> ZoneHit:
    return ZoneHit(zone, "warning", person, scale, 1.2)


def frame(t: float, *hits: ZoneHit, **kw) -> PolicyInputs:
    """A fresh frame captured 20 ms before the decision at ``t``."""
    return PolicyInputs(frame_time=t - 0.02, zone_report=ZoneReport(hits=tuple(hits)), **kw)


def tick(**kw) -> PolicyInputs:
    """A step without a new frame (timers only)."""
    return PolicyInputs(**kw)


def reset(t: float, operator: str = "op7") -> ResetRequest:
    return ResetRequest(operator=operator, time=t, request_id=f"r{t}")


def warmed(config: PolicyConfig = MANUAL, until: float = 1.0):
    """State after clear frames (and fresh poses) from t=0 to ``until`` (RUN from clear_time)."""
    state = initial_state()
    t = 0.0
    while t <= until + 1e-9:
        state, cmd = step(state, frame(t, pose_time=t - 0.01), t, config)
        t = round(t + 0.1, 6)
    return state, cmd


def run(timeline, config=MANUAL, state=None):
    """Apply rows (t, inputs, state, scale or None, reason codes that must be present)."""
    state = state if state is not None else warmed(config)[0]
    commands = []
    for t, inputs, want_state, want_scale, want_codes in timeline:
        state, cmd = step(state, inputs, t, config)
        codes = [r.code for r in cmd.reasons]
        assert cmd.state == want_state, f"t={t}: {cmd.state} != {want_state} ({codes})"
        if want_scale is not None:
            assert cmd.speed_scale == pytest.approx(want_scale), f"t={t}: scale"
        for code in want_codes:
            assert code in codes, f"t={t}: reason {code} missing in {codes}"
        commands.append(cmd)
    return state, commands


def lost(zone: str = "robot-protective", track: int = 3, since: float = 8.1,
         kind: str = "protective", scale: float = 0.0) -> ZoneHit:
    return ZoneHit(zone, kind, 0, scale, None, track_id=track, lost=True, lost_since=since)





STEPS = 40


NAN = float("nan")


CONFIGS = [
    PolicyConfig(),
    PolicyConfig(restart_interlock="auto"),
    PolicyConfig(restart_interlock="auto", clear_time=0.5, separation_monitoring=True),
    PolicyConfig(startup_requires_reset=True, clear_time=0.3, frame_timeout=0.3),
]


FAULTS = (
    Fault("camera_lost", "gone", True, "cam0"),
    Fault("camera_defocused", "blur", False, "cam0"),
    Fault("monitor_stalled", "stalled", True, "service", latch=True),
    Fault("odd", "latch without stop", False, "x", latch=True),
)


@dataclass(frozen=True)
class Step:
    dt: float
    has_frame: bool
    frame_age: float
    hits: tuple[ZoneHit, ...]
    separation: tuple[float, float] | None
    separation_scale: float | None
    faults: tuple[Fault, ...]
    detector_error: bool
    zone_error: bool
    pose_age: float | None
    reset_age: float | None


class _Bits:
    """Decodes one integer into choices, the simplest option first (so hypothesis shrinks a
    failing step towards a plain clear frame). Far cheaper to draw than nested strategies."""

    def __init__(self, value: int) -> None:
        self.value = value

    def pick(self, options):
        self.value, index = divmod(self.value, len(options))
        return options[index]


def _decode(value: int) -> Step:
    b = _Bits(value)
    dt = b.pick((0.1, 0.05, 0.2, 0.01, 0.1, 0.35, 0.6, 1.0, 1.3, 0.1))
    has_frame = b.pick((True, True, True, False))
    frame_age = b.pick((0.02, 0.0, 0.02, 0.1, 0.25, 0.31, 1.0, NAN, -0.5, math.inf))
    hits = [
        ZoneHit(b.pick(("W1", "W2", "P1", "P2")), b.pick(("warning", "protective")),
                b.pick((0, 1, 2)), b.pick((0.5, 0.2, 1.0, 0.0, NAN)),
                track_id=b.pick((None, 7, 8)), lost=b.pick((False, True)),
                lost_since=b.pick((None, 1.0)))
        for _ in range(b.pick((0, 0, 1, 1, 2, 3)))
    ]
    separation = b.pick((None, None, (2.0, 0.8), (0.9, 0.8), (0.2, 0.8), (NAN, 0.8),
                         (math.inf, 0.8), (2.0, NAN), (2.0, math.inf)))
    sep_scale = b.pick((None, None, 1.0, 0.8, 0.3, 0.0, NAN, -1.0))
    faults = tuple(FAULTS[i] for i in b.pick(((), (), (), (0,), (1,), (2,), (3,), (0, 1))))
    detector_error = b.pick((False,) * 9 + (True,))
    zone_error = b.pick((False,) * 19 + (True,))
    pose_age = b.pick((0.01, 0.05, None, 0.2, NAN))
    reset_age = b.pick((None, None, None, 0.0, 0.5, 3.0, NAN))
    return Step(dt, has_frame, frame_age, tuple(hits), separation, sep_scale, faults,
                detector_error, zone_error, pose_age, reset_age)


STEP_BYTES = 11  # enough bits for every choice of one step


def _sequence(raw: bytes) -> list[Step]:
    return [_decode(int.from_bytes(raw[i:i + STEP_BYTES], "little"))
            for i in range(0, len(raw), STEP_BYTES)]


# one draw per sequence: cheap to generate, and shrinks towards zero bytes = clear frames
sequences = st.binary(min_size=STEPS * STEP_BYTES, max_size=STEPS * STEP_BYTES).map(_sequence)


def _inputs(s: Step, now: float) -> PolicyInputs:
    report = ZoneReport(
        hits=s.hits,
        tool_separation_m=s.separation[0] if s.separation else None,
        required_separation_m=s.separation[1] if s.separation else None,
        separation_speed_scale=s.separation_scale,
    )
    return PolicyInputs(
        frame_time=now - s.frame_age if s.has_frame else None,
        zone_report=report if s.has_frame else None,
        faults=s.faults,
        detector_error="detector raised" if s.detector_error else None,
        pose_time=None if s.pose_age is None else now - s.pose_age,
        zone_error="zones.yaml: bad" if s.zone_error else None,
        reset_request=None if s.reset_age is None else ResetRequest("op", now - s.reset_age),
    )
