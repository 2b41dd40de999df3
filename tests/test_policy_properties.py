"""The policy's invariants over random input sequences (hypothesis).

An independent oracle, written from the rules (not from the policy's code), says for each step
which STOP causes the evidence holds; the policy's command must agree with it. The number of
sequences is ``POLICY_PROPERTY_EXAMPLES`` (default 300, 40 steps each); benchmarks/mutation.py and
long runs set it higher.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from monitor.policy import (
    RUN,
    SLOW,
    STOP,
    PolicyConfig,
    PolicyInputs,
    ResetRequest,
    initial_state,
    step,
)
from monitor.types import Fault, ZoneHit, ZoneReport

EXAMPLES = int(os.environ.get("POLICY_PROPERTY_EXAMPLES", "300"))
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


def _zone_stop(s: Step) -> bool:
    """The frame's zone report holds a person (seen or lost) where no motion is allowed."""
    if any(h.kind == "protective" or not h.speed_scale > 0 for h in s.hits):
        return True
    if s.separation is not None:
        d, req = s.separation
        if not (math.isfinite(d) and math.isfinite(req) and d >= req):
            return True
    return s.separation_scale is not None and not s.separation_scale > 0


def _zone_limit(s: Step) -> float:
    """The highest speed scale the frame's warning zones and separation allow."""
    limit = 1.0
    for h in s.hits:
        if h.kind == "warning" and h.speed_scale > 0:
            limit = min(limit, h.speed_scale)
    if s.separation_scale is not None and s.separation_scale > 0:
        limit = min(limit, s.separation_scale)
    return limit


@settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(config=st.sampled_from(CONFIGS), sequence=sequences)
def test_policy_invariants_over_random_sequences(config: PolicyConfig, sequence: list[Step]):
    state = initial_state()
    now = 0.0
    last_frame_now: float | None = None  # now of the last step with a frame
    last_frame_step: Step | None = None  # zone evidence carried over on steps without a frame
    last_stop_cause: float | None = None
    latched_seen = False  # a latch the oracle knows of, released only by an accepted reset
    previous = None
    for s in sequence:
        now = round(now + s.dt, 6)
        state, cmd = step(state, _inputs(s, now), now, config)

        zone = s if s.has_frame else last_frame_step
        zone_stop = zone is not None and _zone_stop(zone)
        fail_safe = (
            last_frame_now is None  # start-up: no frame before this step
            or (not s.has_frame and now - last_frame_now > config.frame_timeout)
            or (s.has_frame and not abs(s.frame_age) <= config.max_frame_age)
            or s.detector_error or s.zone_error
            or any(f.stop or f.latch for f in s.faults)
            or (config.separation_monitoring
                and (s.pose_age is None or not s.pose_age <= config.pose_timeout))
        )
        startup_only = last_frame_now is None and not zone_stop and not (
            (s.has_frame and not abs(s.frame_age) <= config.max_frame_age)
            or s.detector_error or s.zone_error or any(f.stop or f.latch for f in s.faults)
            or (config.separation_monitoring
                and (s.pose_age is None or not s.pose_age <= config.pose_timeout)))
        stop_cause = zone_stop or fail_safe

        # never RUN or SLOW while a STOP cause holds
        if stop_cause:
            assert cmd.state == STOP, (now, cmd)
        # a reset is never accepted while a STOP cause (zone or other) holds
        if cmd.reset is not None and cmd.reset.accepted:
            assert not stop_cause
            latched_seen = False
        # a latch holds until an accepted reset
        latching = any(f.latch for f in s.faults) or (
            config.restart_interlock == "manual" and stop_cause
            and (config.startup_requires_reset or not startup_only))
        if latching:
            assert cmd.latched, (now, cmd)
            latched_seen = True
        if latched_seen:
            assert cmd.state == STOP and cmd.latched
        # speed 0 exactly when STOP; RUN is full speed; SLOW is some motion
        assert (cmd.speed_scale == 0.0) == (cmd.state == STOP)
        assert cmd.state != RUN or cmd.speed_scale == 1.0
        assert cmd.state != SLOW or 0.0 < cmd.speed_scale <= 1.0
        # never faster than this step's warning zones or separation allow
        if zone is not None and cmd.state != STOP:
            assert cmd.speed_scale <= _zone_limit(zone) + 1e-12
        # leave STOP only after clear_time without any STOP cause
        if stop_cause:
            last_stop_cause = now
        if previous is not None and previous.state == STOP and cmd.state != STOP:
            assert last_stop_cause is None or now - last_stop_cause >= config.clear_time - 1e-9
        # every non-RUN command says why; reset possibility is told honestly
        assert cmd.state == RUN or cmd.reasons
        assert cmd.reset_possible == (cmd.latched and not stop_cause)
        assert (cmd.clear_for_s is None) == stop_cause

        if s.has_frame:
            last_frame_now, last_frame_step = now, s
        previous = cmd
