"""The policy's invariants over random input sequences (hypothesis).

An independent oracle, written from the rules (not from the policy's code), says for each step
which STOP causes the evidence holds; the policy's command must agree with it. The number of
sequences is ``POLICY_PROPERTY_EXAMPLES`` (default 300, 40 steps each); benchmarks/mutation.py and
long runs set it higher.
"""

from __future__ import annotations

import math
import os

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from monitor.policy import (
    RUN,
    SLOW,
    STOP,
    PolicyConfig,
    initial_state,
    step,
)
from tests.policy_kit import (
    CONFIGS,
    Step,
    _inputs,
    sequences,
)

EXAMPLES = int(os.environ.get("POLICY_PROPERTY_EXAMPLES", "300"))


















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
