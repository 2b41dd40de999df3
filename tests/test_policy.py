"""The safety policy on scripted timelines: tables of (time, inputs, expected command)."""

from __future__ import annotations

import pytest

from monitor.errors import ConfigError
from monitor.policy import (
    RUN,
    SLOW,
    STOP,
    Command,
    Latch,
    PolicyConfig,
    PolicyInputs,
    Reason,
    ResetOutcome,
    ResetRequest,
    initial_state,
    step,
)
from monitor.types import Fault, ZoneHit, ZoneReport
from tests.policy_kit import AUTO, MANUAL, frame, lost, prot, reset, run, tick, warmed, warn

# --- small factories ---------------------------------------------------------------------------
















# --- start-up ------------------------------------------------------------------------------


def test_startup_is_stop_until_clear_frames_for_clear_time():
    run([
        (0.00, tick(), STOP, 0.0, ["startup"]),
        (0.20, tick(), STOP, 0.0, ["startup"]),
        (0.30, frame(0.30), STOP, 0.0, ["startup"]),  # first frame: start watching
        (0.80, frame(0.80), STOP, 0.0, ["clearing"]),
        (1.29, frame(1.29), STOP, 0.0, ["clearing"]),
        (1.30, frame(1.30), RUN, 1.0, []),  # clear for clear_time: no reset needed
    ], state=initial_state())


def test_startup_with_person_inside_stays_stop_and_latches():
    run([
        (0.0, frame(0.0, prot()), STOP, 0.0, ["protective_zone", "startup"]),
        (0.1, frame(0.1), STOP, 0.0, ["latched"]),
        (2.0, frame(2.0), STOP, 0.0, ["latched"]),
        (2.1, frame(2.1, reset_request=reset(2.1)), RUN, 1.0, []),
    ], state=initial_state())


def test_startup_requires_reset_when_configured():
    config = PolicyConfig(startup_requires_reset=True)
    _state, cmds = run([
        (0.0, frame(0.0), STOP, 0.0, ["startup", "latched"]),
        (1.5, frame(1.5), STOP, 0.0, ["latched"]),
        (1.6, frame(1.6, reset_request=reset(1.6)), RUN, 1.0, []),
    ], config=config, state=initial_state())
    assert cmds[-1].reset is not None and cmds[-1].reset.accepted


# --- zones and hysteresis ----------------------------------------------------------------------


def test_warning_zone_slows_at_once_and_leaves_after_clear_time():
    run([
        (2.0, frame(2.0, warn(scale=0.4)), SLOW, 0.4, ["warning_zone"]),  # no debounce
        (2.1, frame(2.1), SLOW, 0.4, ["clearing"]),
        (2.9, frame(2.9), SLOW, 0.4, ["clearing"]),
        (3.0, frame(3.0), RUN, 1.0, []),
    ])


def test_person_leaving_and_reentering_within_clear_time_restarts_the_timer():
    run([
        (2.0, frame(2.0, warn()), SLOW, 0.5, ["warning_zone"]),
        (2.3, frame(2.3), SLOW, 0.5, ["clearing"]),  # left
        (2.8, frame(2.8, warn()), SLOW, 0.5, ["warning_zone"]),  # back within clear_time
        (3.1, frame(3.1), SLOW, 0.5, ["clearing"]),  # 1.1 s after first exit: still SLOW
        (3.7, frame(3.7), SLOW, 0.5, ["clearing"]),
        (3.8, frame(3.8), RUN, 1.0, []),  # 1.0 s after the last sighting
    ])


def test_protective_reentry_within_clear_time_keeps_stop_auto():
    run([
        (2.0, frame(2.0, prot()), STOP, 0.0, ["protective_zone"]),
        (2.5, frame(2.5), STOP, 0.0, ["clearing"]),
        (2.9, frame(2.9, prot()), STOP, 0.0, ["protective_zone"]),
        (3.5, frame(3.5), STOP, 0.0, ["clearing"]),
        (3.9, frame(3.9), RUN, 1.0, []),
    ], config=AUTO)


def test_speed_scale_lowers_at_once_and_rises_after_clear_time():
    run([
        (2.0, frame(2.0, warn("W1", 0.6)), SLOW, 0.6, []),
        (2.1, frame(2.1, warn("W2", 0.3)), SLOW, 0.3, []),  # deeper zone: lower at once
        (2.2, frame(2.2, warn("W1", 0.6)), SLOW, 0.3, []),  # back out: keep 0.3 ...
        (3.0, frame(3.0, warn("W1", 0.6)), SLOW, 0.3, []),
        (3.1, frame(3.1, warn("W1", 0.6)), SLOW, 0.6, []),  # ... for clear_time
    ])


def test_stop_then_warning_leaves_stop_into_slow():
    run([
        (2.0, frame(2.0, prot(), warn()), STOP, 0.0, ["protective_zone"]),
        (2.1, frame(2.1, warn(scale=0.5)), STOP, 0.0, ["clearing"]),
        (3.0, frame(3.0, warn(scale=0.5)), SLOW, 0.5, ["warning_zone"]),
        (3.5, frame(3.5), SLOW, 0.5, ["clearing"]),
        (4.0, frame(4.0), RUN, 1.0, []),
    ], config=AUTO)


# --- restart interlock and resets --------------------------------------------------------------


def test_manual_interlock_latches_and_refuses_reset_while_occupied():
    state, cmds = run([
        (2.0, frame(2.0, prot("Z1", person=3)), STOP, 0.0, ["protective_zone", "latched"]),
        (2.5, frame(2.5, prot("Z1", person=3), reset_request=reset(2.5)), STOP, 0.0,
         ["protective_zone"]),
        (2.6, frame(2.6), STOP, 0.0, ["clearing", "latched"]),
        (4.0, frame(4.0), STOP, 0.0, ["latched"]),  # cause gone long ago: still latched
        (4.1, frame(4.1, reset_request=reset(4.1)), RUN, 1.0, []),
    ])
    refused = cmds[1].reset
    assert refused is not None and not refused.accepted
    assert "Z1" in refused.message and "person 3" in refused.message
    assert cmds[4].reset.accepted and cmds[4].reset.operator == "op7"
    assert state.last_reset.accepted


def test_reset_before_clear_time_waits_for_clear_time():
    run([
        (2.0, frame(2.0, prot()), STOP, 0.0, ["latched"]),
        (2.2, frame(2.2, reset_request=reset(2.2)), STOP, 0.0, ["clearing"]),
        (2.9, frame(2.9), STOP, 0.0, ["clearing"]),
        (3.0, frame(3.0), RUN, 1.0, []),
    ])


def test_cause_after_accepted_reset_latches_again():
    run([
        (2.0, frame(2.0, prot()), STOP, 0.0, []),
        (2.2, frame(2.2, reset_request=reset(2.2)), STOP, 0.0, ["clearing"]),
        (2.5, frame(2.5, prot()), STOP, 0.0, ["latched"]),
        (4.0, frame(4.0), STOP, 0.0, ["latched"]),
    ])


def test_old_reset_and_reset_without_latch_are_refused():
    state, _ = run([(2.0, frame(2.0, prot()), STOP, 0.0, [])])
    state, cmd = step(state, frame(3.5, reset_request=reset(0.5)), 3.5, MANUAL)
    assert cmd.state == STOP and not cmd.reset.accepted and "old" in cmd.reset.message
    state, _ = warmed()
    state, cmd = step(state, frame(2.0, reset_request=reset(2.0)), 2.0, MANUAL)
    assert cmd.state == RUN and not cmd.reset.accepted and "nothing to reset" in cmd.reset.message


def test_warning_zone_never_latches():
    run([
        (2.0, frame(2.0, warn()), SLOW, 0.5, []),
        (3.0, frame(3.0), RUN, 1.0, []),
    ])


# --- fail-safe causes --------------------------------------------------------------------------

SEP = PolicyConfig(separation_monitoring=True, restart_interlock="auto")


@pytest.mark.parametrize(("cause_inputs", "code", "config"), [
    pytest.param(lambda t: tick(), "frame_timeout", AUTO, id="frame_timeout"),
    pytest.param(lambda t: frame(t, detector_error="onnxruntime: bad input"), "detector_error",
                 AUTO, id="detector_raises"),
    pytest.param(lambda t: PolicyInputs(frame_time=t - 0.5, zone_report=ZoneReport()),
                 "frame_stale", AUTO, id="frame_older_than_max_frame_age"),
    pytest.param(lambda t: frame(t, pose_time=t - 0.3), "pose_stale", SEP, id="pose_stale"),
    pytest.param(lambda t: frame(t, pose_time=None), "pose_stale", SEP, id="pose_never_seen"),
    pytest.param(lambda t: frame(t, zone_error="zones.yaml: zone Z1 has 2 points"),
                 "zone_invalid", AUTO, id="zone_file_invalid"),
    pytest.param(lambda t: frame(t, faults=(Fault("camera_frozen", "same frame 2 s", True,
                                                  "cam0"),)), "fault", AUTO, id="stop_fault"),
])
def test_every_fail_safe_cause_stops_and_clears_after_clear_time(cause_inputs, code, config):
    def good(t):
        return frame(t, pose_time=t - 0.01)

    state = initial_state()
    for i in range(12):  # clear frames (with fresh pose) until RUN
        state, cmd = step(state, good(i / 10), i / 10, config)
    assert cmd.state == RUN
    # frame_timeout needs the time to pass without frames; the others fire on the first step
    t = 1.1 + (config.frame_timeout + 0.01 if code == "frame_timeout" else 0.1)
    state, cmd = step(state, cause_inputs(t), t, config)
    assert cmd.state == STOP and cmd.speed_scale == 0.0
    assert code in [r.code for r in cmd.reasons]
    # cause gone: STOP holds for clear_time, then RUN (auto interlock)
    t2 = round(t + 0.1, 6)
    state, cmd = step(state, good(t2), t2, config)
    assert cmd.state == STOP and "clearing" in [r.code for r in cmd.reasons]
    state, cmd = step(state, good(t + 1.0), t + 1.0, config)
    assert cmd.state == RUN


def test_frame_timeout_fires_from_ticks_and_latches_with_manual_interlock():
    run([
        (1.3, tick(), RUN, 1.0, []),
        (1.5, tick(), RUN, 1.0, []),  # 0.5 s since the last frame: not yet
        (1.51, tick(), STOP, 0.0, ["frame_timeout", "latched"]),
        (1.6, frame(1.6), STOP, 0.0, ["latched"]),
        (3.0, frame(3.0, reset_request=reset(3.0)), RUN, 1.0, []),
    ])


def test_warning_fault_does_not_stop():
    _state, cmd = step(warmed()[0], frame(1.1, faults=(Fault("camera_defocused", "blur", False),)),
                      1.1, MANUAL)
    assert cmd.state == RUN


def test_tick_without_frame_never_clears_a_zone_cause():
    config = PolicyConfig(restart_interlock="auto", clear_time=0.2, frame_timeout=0.5)
    run([
        (2.0, frame(2.0, prot()), STOP, 0.0, ["protective_zone"]),
        (2.3, tick(), STOP, 0.0, ["protective_zone"]),  # last frame showed a person
        (2.4, frame(2.4), STOP, 0.0, ["clearing"]),
        (2.6, frame(2.6), RUN, 1.0, []),
    ], config=config, state=warmed(config, until=1.9)[0])


def _sep(t, d=None, req=None, scale=None):
    return PolicyInputs(frame_time=t - 0.02, pose_time=t - 0.01, zone_report=ZoneReport(
        tool_separation_m=d, required_separation_m=req, separation_speed_scale=scale))


def test_separation_below_required_stops():
    state = warmed(SEP)[0]
    state, cmds = run([
        (1.1, _sep(1.1, 2.0, 0.8), RUN, 1.0, []),
        (1.2, _sep(1.2, 0.5, 0.8), STOP, 0.0, ["separation"]),
    ], config=SEP, state=state)
    stop_reason = next(r for r in cmds[-1].reasons if r.code == "separation")
    assert stop_reason.distance_m == pytest.approx(0.5)
    assert stop_reason.required_m == pytest.approx(0.8)


@pytest.mark.parametrize(("d", "req"), [
    pytest.param(float("nan"), 0.8, id="separation_nan"),
    pytest.param(float("inf"), 0.8, id="separation_inf"),
    pytest.param(2.0, float("nan"), id="required_nan"),
    pytest.param(2.0, float("inf"), id="required_inf"),
])
def test_non_finite_separation_stops(d, req):
    _state, cmd = step(warmed(SEP)[0], _sep(1.1, d, req), 1.1, SEP)
    assert cmd.state == STOP and "separation" in [r.code for r in cmd.reasons]


@pytest.mark.parametrize("scale", [0.0, -0.1, float("nan")])
def test_separation_speed_scale_zero_or_nan_stops(scale):
    _state, cmd = step(warmed(SEP)[0], _sep(1.1, 1.0, 0.8, scale), 1.1, SEP)
    assert cmd.state == STOP and "separation" in [r.code for r in cmd.reasons]


def test_separation_speed_scale_slows_at_that_scale_and_lowest_wins():
    state = warmed(SEP)[0]
    run([
        (1.1, _sep(1.1, 1.5, 0.8, 1.0), RUN, 1.0, []),
        (1.2, _sep(1.2, 1.2, 0.8, 0.45), SLOW, 0.45, ["separation_speed"]),
        (1.3, _sep(1.3, 1.3, 0.8, 0.7), SLOW, 0.45, ["separation_speed"]),  # rises late
        (2.2, _sep(2.2, 1.3, 0.8, 0.7), SLOW, 0.7, ["separation_speed"]),
    ], config=SEP, state=state)
    # with a warning zone: the lower of both
    for zone_scale, sep_scale, want in ((0.3, 0.6, 0.3), (0.8, 0.4, 0.4)):
        inputs = PolicyInputs(frame_time=1.08, pose_time=1.09, zone_report=ZoneReport(
            hits=(warn(scale=zone_scale),), tool_separation_m=1.2, required_separation_m=0.8,
            separation_speed_scale=sep_scale))
        _s, cmd = step(warmed(SEP)[0], inputs, 1.1, SEP)
        assert (cmd.state, cmd.speed_scale) == (SLOW, pytest.approx(want))


def test_reasons_carry_zone_person_distance_and_fault_names():
    _, cmd = step(warmed()[0], frame(1.1, prot("Z9", person=2, distance=0.0), faults=(
        Fault("camera_lost", "no frames", True, "cam1"),)), 1.1, MANUAL)
    zone = next(r for r in cmd.reasons if r.code == "protective_zone")
    assert (zone.zone_id, zone.person, zone.distance_m) == ("Z9", 2, 0.0)
    fault = next(r for r in cmd.reasons if r.code == "fault")
    assert (fault.fault, fault.source) == ("camera_lost", "cam1")
    assert cmd.to_dict()["reasons"][0]["code"]


def test_replay_is_deterministic():
    timeline = [frame(t / 10, *([prot()] if 12 <= t < 15 else [])) for t in range(40)]

    def replay():
        state, out = initial_state(), []
        for i, inputs in enumerate(timeline):
            state, cmd = step(state, inputs, i / 10, AUTO)
            out.append(cmd)
        return out

    assert replay() == replay()


@pytest.mark.parametrize("kwargs", [
    {"restart_interlock": "sometimes"}, {"clear_time": 0}, {"frame_timeout": -1},
    {"max_frame_age": float("nan")}, {"reset_max_age": float("inf")},
])
def test_bad_config_is_a_config_error(kwargs):
    with pytest.raises(ConfigError):
        PolicyConfig(**kwargs)


# --- every (state, input) pair -----------------------------------------------------------------


def _state_in(name: str):
    """(state, time) in one of the policy's situations, manual interlock."""
    state, _ = warmed()
    if name == "RUN":
        return state, 1.0
    if name == "SLOW":
        state, _ = step(state, frame(1.1, warn()), 1.1, MANUAL)
        return state, 1.1
    state, _ = step(state, frame(1.1, prot()), 1.1, MANUAL)
    if name == "STOP_cause_just_seen":
        return state, 1.1
    for t in (1.2, 1.6, 2.0, 2.4):  # cause gone for longer than clear_time: latched only
        state, _ = step(state, frame(t), t, MANUAL)
    return state, 2.4


_INPUTS = {
    "clear": lambda t: frame(t),
    "warning": lambda t: frame(t, warn()),
    "protective": lambda t: frame(t, prot()),
    "stop_fault": lambda t: frame(t, faults=(Fault("camera_lost", "gone"),)),
    "tick": lambda t: tick(),
    "reset": lambda t: frame(t, reset_request=reset(t)),
}

_EXPECTED = {  # state before -> input -> state after (0.1 s later)
    "RUN": {"clear": RUN, "warning": SLOW, "protective": STOP, "stop_fault": STOP,
            "tick": RUN, "reset": RUN},
    "SLOW": {"clear": SLOW, "warning": SLOW, "protective": STOP, "stop_fault": STOP,
             "tick": SLOW, "reset": SLOW},
    "STOP_cause_just_seen": {"clear": STOP, "warning": STOP, "protective": STOP,
                             "stop_fault": STOP, "tick": STOP, "reset": STOP},
    "STOP_latched": {"clear": STOP, "warning": STOP, "protective": STOP, "stop_fault": STOP,
                     "tick": STOP, "reset": RUN},
}


@pytest.mark.parametrize(("before", "given", "after"), [
    pytest.param(b, i, a, id=f"{b}-{i}") for b, row in _EXPECTED.items() for i, a in row.items()
])
def test_state_input_table(before, given, after):
    state, t = _state_in(before)
    state, cmd = step(state, _INPUTS[given](t + 0.1), t + 0.1, MANUAL)
    assert cmd.state == after
    assert (cmd.speed_scale == 0.0) == (after == STOP)
    if after != RUN:
        assert cmd.reasons, "every non-RUN command says why"


def test_the_same_hits_in_another_order_are_the_same_command():
    from monitor.policy import PolicyInputs, initial_state, step
    from monitor.types import ZoneHit, ZoneReport

    a, b = ZoneHit("B", "protective", 0, 0.0), ZoneHit("A", "protective", 0, 0.0)
    state, cfg = initial_state(), PolicyConfig()
    commands = []
    for k, hits in enumerate([(a, b), (a, b), (b, a)]):
        state, cmd = step(state, PolicyInputs(frame_time=0.1 * k, zone_report=ZoneReport(hits)),
                          0.1 * k, cfg)
        commands.append(cmd)
    assert [r.zone_id for r in commands[2].reasons if r.zone_id] == ["A", "B"]
    assert commands[2].same_as(commands[1])  # nothing new to announce on the wire


# --- lost persons, latching faults, the latched state told honestly ------------------------------




def test_person_lost_in_protective_zone_stops_and_refuses_reset_with_confirm_clear_hint():
    _state, cmds = run([
        (8.2, frame(8.2, lost()), STOP, 0.0, ["person_lost", "latched"]),
        (8.3, frame(8.3, lost(), reset_request=reset(8.3)), STOP, 0.0, ["person_lost"]),
        (8.4, tick(), STOP, 0.0, ["person_lost"]),  # carried over without a frame
    ], state=warmed(until=8.1)[0])
    cause = next(r for r in cmds[0].reasons if r.code == "person_lost")
    # the time stays a number: the edges write it in the operator's clock
    assert cause.message == "person 3 lost inside robot-protective"
    assert cause.since == 8.1 and cause.to_dict()["since"] == 8.1
    assert (cause.zone_id, cause.person) == ("robot-protective", 3)
    refused = cmds[1].reset
    assert not refused.accepted
    assert "person 3 lost inside robot-protective" in refused.message
    assert "monitor reset --confirm-clear" in refused.message
    assert cmds[1].describe() == (
        "STOP latched by person 3 lost inside robot-protective at 8.2 s; holding now: "
        "person 3 lost inside robot-protective since 8.1 s; no reset until they clear")
    assert "1059" not in cmds[1].describe(lambda t: "14:03:12")
    assert cmds[1].describe(lambda t: "14:03:12").count("14:03:12") == 2
    assert not cmds[1].reset_possible and cmds[1].clear_for_s is None


def test_person_lost_in_warning_zone_keeps_slow():
    _s, cmd = step(warmed()[0], frame(1.1, lost("W1", kind="warning", scale=0.4)), 1.1, MANUAL)
    assert (cmd.state, cmd.speed_scale) == (SLOW, pytest.approx(0.4))
    assert [r.code for r in cmd.reasons] == ["warning_zone"]
    assert "lost inside W1" in cmd.reasons[0].message


@pytest.mark.parametrize("scale", [0.0, float("nan")])
def test_warning_zone_with_speed_scale_zero_or_nan_stops(scale):
    _s, cmd = step(warmed(AUTO)[0], frame(1.1, warn(scale=scale)), 1.1, AUTO)
    assert cmd.state == STOP and cmd.speed_scale == 0.0
    assert [r.code for r in cmd.reasons] == ["protective_zone"]


def test_latching_fault_latches_even_with_auto_interlock():
    stall = Fault("monitor_stalled", "no step for 2 s", True, "service", latch=True)
    _state, cmds = run([
        (1.1, frame(1.1, faults=(stall,)), STOP, 0.0, ["fault", "latched"]),
        (1.2, frame(1.2), STOP, 0.0, ["latched"]),
        (3.0, frame(3.0), STOP, 0.0, ["latched"]),  # clear for long: still latched
        (3.1, frame(3.1, reset_request=reset(3.1)), RUN, 1.0, []),
    ], config=AUTO, state=warmed(AUTO)[0])
    assert cmds[0].latched_by.code == "fault" and "monitor_stalled" in cmds[0].latched_by.message
    # a latch fault that forgot stop=True still stops
    _s, cmd = step(warmed(AUTO)[0], frame(1.1, faults=(Fault("x", "y", False, latch=True),)),
                   1.1, AUTO)
    assert cmd.state == STOP and cmd.latched


def test_auto_interlock_does_not_latch_ordinary_causes():
    _s, cmd = step(warmed(AUTO)[0], frame(1.1, prot()), 1.1, AUTO)
    assert cmd.state == STOP and not cmd.latched and cmd.latched_by is None


def test_latched_state_says_by_whom_how_long_clear_and_when_reset_became_possible():
    state, cmds = run([
        (5.5, frame(5.5, prot("robot-protective", 0)), STOP, 0.0, ["latched"]),
        (5.6, frame(5.6, prot("robot-protective", 0)), STOP, 0.0, ["latched"]),
        (5.7, frame(5.7), STOP, 0.0, ["latched"]),
        (6.5, frame(6.5), STOP, 0.0, ["latched"]),
        (8.0, frame(8.0), STOP, 0.0, ["latched"]),
    ], state=warmed(until=5.4)[0])
    first, still, possible, later, much_later = cmds
    assert first.latched_by.to_dict() == {"code": "protective_zone", "at": 5.5,
                                          "message": "person 0 in robot-protective",
                                          "zone_id": "robot-protective", "person": 0,
                                          "nonce": "latch-1"}
    assert first.describe() == ("STOP latched by person 0 in robot-protective at 5.5 s; "
                                "holding now: person 0 in robot-protective; no reset until "
                                "they clear")
    assert not first.reset_possible and first.clear_for_s is None
    assert still.same_as(first)
    assert possible.reset_possible and possible.reset_possible_since == 5.7
    assert possible.clear_for_s == pytest.approx(0.1)
    assert not possible.same_as(still)  # the moment a reset becomes possible is news
    assert later.same_as(possible)  # still clearing, still possible: nothing new
    assert not much_later.same_as(later)  # clear_time over: the "clearing" reason went
    assert much_later.reset_possible_since == 5.7
    assert much_later.clear_for_s == pytest.approx(2.4)
    assert much_later.describe() == ("STOP latched by person 0 in robot-protective at 5.5 s; "
                                     "no STOP cause now (clear for 2.4 s): reset possible")
    assert possible.describe() == ("STOP latched by person 0 in robot-protective at 5.5 s; "
                                   "no STOP cause now (clear for 0.1 s): reset possible")
    d = much_later.to_dict()
    assert d["latched_by"]["person"] == 0 and d["reset_possible"] is True
    assert d["clear_for_s"] == pytest.approx(2.4) and d["reset_possible_since"] == 5.7
    # the clear_for value moving every frame is no change to announce
    _s, again = step(state, frame(8.1), 8.1, MANUAL)
    assert again.same_as(much_later) and again.clear_for_s != much_later.clear_for_s


def test_describe_run_slow_stop():
    assert step(warmed()[0], frame(1.1), 1.1, MANUAL)[1].describe() == "RUN"
    assert step(warmed()[0], frame(1.1, warn("W1", 0.4)), 1.1, MANUAL)[1].describe() == \
        "SLOW x0.40: person 0 in W1"
    assert step(warmed(AUTO)[0], frame(1.1, prot("Z1")), 1.1, AUTO)[1].describe() == \
        "STOP: person 0 in Z1"


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_times_are_stale(bad):
    _s, cmd = step(warmed(SEP)[0], PolicyInputs(frame_time=bad, zone_report=ZoneReport(),
                                                pose_time=1.09), 1.1, SEP)
    assert cmd.state == STOP and "frame_stale" in [r.code for r in cmd.reasons]
    _s, cmd = step(warmed(SEP)[0], PolicyInputs(frame_time=1.08, zone_report=ZoneReport(),
                                                pose_time=bad), 1.1, SEP)
    assert cmd.state == STOP and "pose_stale" in [r.code for r in cmd.reasons]
    state = warmed()[0]
    state, _ = step(state, frame(1.1, prot()), 1.1, MANUAL)
    _s, cmd = step(state, frame(3.0, reset_request=ResetRequest("op", bad)), 3.0, MANUAL)
    assert cmd.state == STOP and not cmd.reset.accepted and "old" in cmd.reset.message


def test_frame_from_the_future_is_stale():
    _s, cmd = step(warmed(AUTO)[0], PolicyInputs(frame_time=5.0, zone_report=ZoneReport()), 1.1,
                   AUTO)
    assert cmd.state == STOP and "frame_stale" in [r.code for r in cmd.reasons]


def test_now_must_be_finite():
    with pytest.raises(ValueError, match="not finite"):
        step(initial_state(), tick(), float("nan"), MANUAL)


# --- every (phase, input) pair, and each timer's expiry -----------------------------------------

_LATCH_FAULT = Fault("monitor_stalled", "stalled", True, "service", latch=True)
_MORE_INPUTS = {
    **_INPUTS,
    "lost": lambda t: frame(t, lost(since=t - 0.5)),
    "latch_fault": lambda t: frame(t, faults=(_LATCH_FAULT,)),
    "stale_frame": lambda t: PolicyInputs(frame_time=t - 1.0, zone_report=ZoneReport()),
    "detector_error": lambda t: frame(t, detector_error="boom"),
}


def _phase_state(phase: str, config: PolicyConfig):
    """(state, time) in the named phase of the machine."""
    state, _ = warmed(config)
    steps = {
        "RUN": [],
        "SLOW_ACTIVE": [(1.1, frame(1.1, warn()))],
        "SLOW_CLEARING": [(1.1, frame(1.1, warn())), (1.2, frame(1.2))],
        "STOP_ACTIVE": [(1.1, frame(1.1, prot()))],
        "STOP_CLEARING": [(1.1, frame(1.1, prot())), (1.2, frame(1.2))],
        "STOP_LATCHED": [(1.1, frame(1.1, prot())), (1.2, frame(1.2)), (1.6, frame(1.6)),
                         (2.0, frame(2.0)), (2.2, frame(2.2))],
    }[phase]
    t = 1.0
    for t, inputs in steps:
        state, _ = step(state, inputs, t, config)
    assert state.phase == phase
    return state, t


_PHASE_TABLE_MANUAL = {  # phase before -> input -> phase after (0.1 s later), manual interlock
    "RUN": dict(clear="RUN", warning="SLOW_ACTIVE", protective="STOP_ACTIVE",
                stop_fault="STOP_ACTIVE", tick="RUN", reset="RUN", lost="STOP_ACTIVE",
                latch_fault="STOP_ACTIVE", stale_frame="STOP_ACTIVE",
                detector_error="STOP_ACTIVE"),
    "SLOW_ACTIVE": dict(clear="SLOW_CLEARING", warning="SLOW_ACTIVE", protective="STOP_ACTIVE",
                        stop_fault="STOP_ACTIVE", tick="SLOW_ACTIVE", reset="SLOW_CLEARING",
                        lost="STOP_ACTIVE", latch_fault="STOP_ACTIVE",
                        stale_frame="STOP_ACTIVE", detector_error="STOP_ACTIVE"),
    "SLOW_CLEARING": dict(clear="SLOW_CLEARING", warning="SLOW_ACTIVE",
                          protective="STOP_ACTIVE", stop_fault="STOP_ACTIVE",
                          tick="SLOW_CLEARING", reset="SLOW_CLEARING", lost="STOP_ACTIVE",
                          latch_fault="STOP_ACTIVE", stale_frame="STOP_ACTIVE",
                          detector_error="STOP_ACTIVE"),
    "STOP_ACTIVE": dict(clear="STOP_LATCHED", warning="STOP_LATCHED", protective="STOP_ACTIVE",
                        stop_fault="STOP_ACTIVE", tick="STOP_ACTIVE", reset="STOP_CLEARING",
                        lost="STOP_ACTIVE", latch_fault="STOP_ACTIVE",
                        stale_frame="STOP_ACTIVE", detector_error="STOP_ACTIVE"),
    "STOP_LATCHED": dict(clear="STOP_LATCHED", warning="STOP_LATCHED",
                         protective="STOP_ACTIVE", stop_fault="STOP_ACTIVE",
                         tick="STOP_LATCHED", reset="RUN", lost="STOP_ACTIVE",
                         latch_fault="STOP_ACTIVE", stale_frame="STOP_ACTIVE",
                         detector_error="STOP_ACTIVE"),
}
_PHASE_TABLE_AUTO = {
    "STOP_ACTIVE": dict(clear="STOP_CLEARING", warning="STOP_CLEARING",
                        protective="STOP_ACTIVE", tick="STOP_ACTIVE", reset="STOP_CLEARING",
                        latch_fault="STOP_ACTIVE"),
    "STOP_CLEARING": dict(clear="STOP_CLEARING", warning="STOP_CLEARING",
                          protective="STOP_ACTIVE", tick="STOP_CLEARING",
                          reset="STOP_CLEARING", lost="STOP_ACTIVE", stop_fault="STOP_ACTIVE",
                          latch_fault="STOP_ACTIVE", stale_frame="STOP_ACTIVE"),
}


@pytest.mark.parametrize(("config", "before", "given", "after"), [
    pytest.param(cfg, b, i, a, id=f"{name}-{b}-{i}")
    for name, cfg, table in (("manual", MANUAL, _PHASE_TABLE_MANUAL),
                             ("auto", AUTO, _PHASE_TABLE_AUTO))
    for b, row in table.items() for i, a in row.items()
])
def test_phase_input_table(config, before, given, after):
    state, t = _phase_state(before, config)
    state, cmd = step(state, _MORE_INPUTS[given](t + 0.1), round(t + 0.1, 6), config)
    assert cmd.phase == after == state.phase
    assert (cmd.speed_scale == 0.0) == (cmd.state == STOP)
    assert cmd.latched == (after == "STOP_LATCHED" or (
        after == "STOP_ACTIVE" and (config is MANUAL or given == "latch_fault")
    ) or (before == "STOP_LATCHED" and after == "STOP_ACTIVE"))
    if given == "latch_fault":
        assert cmd.latched


@pytest.mark.parametrize(("phase", "config", "after_clear", "expiry"), [
    pytest.param("SLOW_CLEARING", MANUAL, "RUN", 1.1 + 1.0, id="slow_clear_time"),
    pytest.param("STOP_CLEARING", AUTO, "RUN", 1.1 + 1.0, id="stop_clear_time"),
])
def test_each_clear_timer_expires_exactly_at_clear_time(phase, config, after_clear, expiry):
    state, _t = _phase_state(phase, config)
    s1, before = step(state, frame(expiry - 0.001), expiry - 0.001, config)
    assert before.phase == phase
    _s, at = step(s1, frame(expiry), expiry, config)
    assert at.phase == after_clear


def test_frame_timeout_and_reset_age_expire_at_their_limits():
    state, _ = warmed(AUTO)  # last frame at 1.0
    _s, cmd = step(state, tick(), 1.0 + AUTO.frame_timeout, AUTO)
    assert cmd.state == RUN
    _s, cmd = step(state, tick(), 1.0 + AUTO.frame_timeout + 0.001, AUTO)
    assert "frame_timeout" in [r.code for r in cmd.reasons]
    state, _ = step(warmed()[0], frame(1.1, prot()), 1.1, MANUAL)
    state, _ = step(state, frame(2.2), 2.2, MANUAL)
    _s, cmd = step(state, frame(4.2, reset_request=reset(2.2)), 4.2, MANUAL)
    assert cmd.reset.accepted  # exactly reset_max_age old: still fresh
    _s, cmd = step(state, frame(4.21, reset_request=reset(2.2)), 4.21, MANUAL)
    assert not cmd.reset.accepted and cmd.state == STOP


# --- exact texts and fields (what operators and controllers read) -------------------------------


def test_separation_equal_to_required_is_enough():
    _s, cmd = step(warmed(SEP)[0], _sep(1.1, 0.8, 0.8), 1.1, SEP)
    assert cmd.state == RUN
    _s, cmd = step(warmed(SEP)[0], _sep(1.1, 0.5, 0.8), 1.1, SEP)
    assert [r.message for r in cmd.reasons] == ["separation 0.500 m < required 0.800 m"]


def test_reason_texts_and_distances():
    hit = ZoneHit("Z1", "protective", 2, 0.0, 0.25, track_id=None, lost=True)
    _s, cmd = step(warmed(AUTO)[0], frame(1.1, hit), 1.1, AUTO)
    (r,) = cmd.reasons
    assert (r.code, r.message, r.person, r.distance_m) == (
        "person_lost", "person 2 lost inside Z1", 2, 0.25)
    _s, cmd = step(warmed(AUTO)[0], frame(1.1, ZoneHit("W1", "warning", 0, 0.5, 1.5,
                                                        track_id=9)), 1.1, AUTO)
    (r,) = cmd.reasons
    assert (r.code, r.message, r.person, r.distance_m) == ("warning_zone", "person 9 in W1",
                                                          9, 1.5)
    state, _ = step(warmed(AUTO)[0], frame(1.1, prot()), 1.1, AUTO)
    _s, cmd = step(state, frame(1.2), 1.2, AUTO)
    assert cmd.reasons[-1].message == "causes absent for 0.100 s of 1.0 s"
    assert cmd.describe() == ("STOP: clearing, causes absent for 0.100 s of 1.0 s "
                              "(was: person 0 in Z1)")


def test_warning_zone_scale_above_one_is_capped_at_full_speed():
    state = warmed()[0]
    for t in (1.1, 1.6, 2.1, 2.6):  # longer than clear_time: no earlier scale in the window
        state, cmd = step(state, frame(t, warn(scale=1.5)), t, MANUAL)
        assert (cmd.state, cmd.speed_scale) == (SLOW, 1.0)


def test_reset_refusal_names_every_cause():
    state, _ = step(warmed()[0], frame(1.1, prot("Z1", 0), prot("Z2", 1)), 1.1, MANUAL)
    _s, cmd = step(state, frame(1.2, prot("Z1", 0), prot("Z2", 1), reset_request=reset(1.2)),
                   1.2, MANUAL)
    assert cmd.reset.message == "refused: person 0 in Z1; person 1 in Z2"


def test_describe_of_commands_made_elsewhere():
    assert Command(STOP, 0.0).describe() == "STOP: no cause given"
    two = Command(STOP, 0.0, (Reason("fault", "a: x"), Reason("fault", "b: y")))
    assert two.describe() == "STOP: a: x; b: y"
    latched = Command(STOP, 0.0, (Reason("fault", "a: x"), Reason("fault", "b: y"),
                                  Reason("latched", "waiting")), latched=True)
    assert latched.describe() == "STOP latched; holding now: a: x; b: y; no reset until they clear"
    possible = Command(STOP, 0.0, latched=True, reset_possible=True,
                       latched_by=Latch("fault", "a: x", 2.0))
    assert possible.describe() == "STOP latched by a: x at 2.0 s; no STOP cause now: reset possible"


def test_command_to_dict_has_every_field():
    state, _ = step(warmed()[0], frame(1.1, prot()), 1.1, MANUAL)
    _s, cmd = step(state, frame(1.2, prot(), reset_request=reset(1.2)), 1.2, MANUAL)
    d = cmd.to_dict()
    assert d["state"] == STOP and d["speed_scale"] == 0.0 and d["since"] == 1.1
    assert d["latched"] is True and d["reset_possible"] is False and d["clear_for_s"] is None
    assert d["reset"] == {"operator": "op7", "accepted": False, "request_id": "r1.2",
                          "message": "refused: person 0 in Z1"}
    assert d["latched_by"]["code"] == "protective_zone" and "reset_possible_since" not in d
    assert [r["code"] for r in d["reasons"]] == ["protective_zone", "latched"]


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"restart_interlock": "sometimes"},
     "policy.restart_interlock: should be 'manual' or 'auto' (got 'sometimes')"),
    ({"clear_time": 0}, "policy.clear_time: should be greater than 0 (got 0)"),
    ({"pose_timeout": "1"}, "policy.pose_timeout: should be a valid number (got a string)"),
])
def test_config_errors_name_the_key_and_value(kwargs, message):
    with pytest.raises(ConfigError) as err:
        PolicyConfig(**kwargs)
    assert str(err.value) == message


def _reasons(cmd) -> list[dict]:
    return [r.to_dict() for r in cmd.reasons]


def test_every_fail_safe_reason_exactly():
    _s, cmd = step(initial_state(), tick(), 0.0, MANUAL)
    assert _reasons(cmd) == [{"code": "startup", "message": "no frame processed yet"}]
    _s, cmd = step(initial_state(), frame(0.0), 0.0, MANUAL)
    assert _reasons(cmd) == [{"code": "startup",
                              "message": "first frame: watching the cell for clear_time"}]
    _s, cmd = step(warmed(AUTO)[0], tick(), 1.625, AUTO)
    assert _reasons(cmd) == [{"code": "frame_timeout", "message": "no frame for 0.625 s (> 0.5 s)"}]
    faults = (Fault("camera_lost", "gone", True, "cam1"), Fault("odd", "why", True),
              Fault("blur", "soft", False, "cam1"))
    inputs = PolicyInputs(frame_time=0.6, zone_report=ZoneReport(), detector_error="boom",
                          zone_error="bad zone", pose_time=1.0, faults=faults)
    _s, cmd = step(warmed(SEP)[0], inputs, 1.125, SEP)
    assert _reasons(cmd) == [
        {"code": "frame_stale", "message": "frame is 0.525 s old (> 0.3 s)"},
        {"code": "detector_error", "message": "boom", "fault": "detector_error",
         "source": "detector"},
        {"code": "zone_invalid", "message": "bad zone", "fault": "zone_invalid",
         "source": "zones"},
        {"code": "pose_stale", "message": "tool pose is 0.125 s old (> 0.1 s)",
         "fault": "pose_stale", "source": "pose"},
        {"code": "fault", "message": "camera_lost: gone", "fault": "camera_lost",
         "source": "cam1"},
        {"code": "fault", "message": "odd: why", "fault": "odd"},
    ]
    _s, cmd = step(warmed(SEP)[0], frame(1.1, pose_time=None), 1.1, SEP)
    assert _reasons(cmd) == [{"code": "pose_stale", "message": "no tool pose received",
                              "fault": "pose_stale", "source": "pose"}]


def test_separation_reasons_exactly():
    _s, cmd = step(warmed(SEP)[0], _sep(1.1, 1.0, 0.8, 0.0), 1.1, SEP)
    assert _reasons(cmd) == [{"code": "separation", "distance_m": 1.0, "required_m": 0.8,
                              "message": "separation speed scale 0.00: no robot speed is safe "
                                         "at this separation"}]
    _s, cmd = step(warmed(SEP)[0], _sep(1.1, 1.0, 0.8, 0.45), 1.1, SEP)
    assert _reasons(cmd) == [{"code": "separation_speed", "distance_m": 1.0, "required_m": 0.8,
                              "message": "separation allows 0.45 of the programmed speed"}]


def test_reset_and_latch_texts_exactly():
    state, cmd = step(warmed()[0], frame(1.1, prot()), 1.1, MANUAL)
    assert cmd.reasons[-1] == Reason("latched", "STOP latched: waiting for an operator reset")
    _s, old = step(state, frame(3.5, reset_request=reset(1.0)), 3.5, MANUAL)
    assert old.reset == ResetOutcome("op7", False, "refused: request is 2.5 s old", "r1.0")
    _s, lost_cmd = step(state, frame(1.2, lost(track=4, since=1.15),
                                     reset_request=reset(1.2)), 1.2, MANUAL)
    assert lost_cmd.reset.message == (
        "refused: person 4 lost inside robot-protective (wait until the person is "
        "seen leaving, or `monitor reset --confirm-clear` after looking)")
    for t in (1.2, 1.6, 2.0, 2.2):
        state, _ = step(state, frame(t), t, MANUAL)
    _s, ok = step(state, frame(2.3, reset_request=reset(2.3)), 2.3, MANUAL)
    assert ok.reset == ResetOutcome("op7", True, "reset accepted", "r2.3")
    _s, none = step(warmed()[0], frame(1.1, reset_request=reset(1.1)), 1.1, MANUAL)
    assert none.reset == ResetOutcome("op7", False, "nothing to reset: not latched", "r1.1")
    stall = Fault("monitor_stalled", "no step for 2 s", True, "service", latch=True)
    _s, cmd = step(warmed(AUTO)[0], frame(1.1, faults=(stall,)), 1.1, AUTO)
    assert cmd.latched_by == Latch("fault", "monitor_stalled: no step for 2 s", 1.1,
                                   nonce="latch-1")


def test_tick_without_frame_keeps_the_last_frames_speed_scale():
    config = PolicyConfig(restart_interlock="auto", clear_time=0.2, frame_timeout=0.5)
    run([
        (2.0, frame(2.0, warn(scale=0.4)), SLOW, 0.4, ["warning_zone"]),
        (2.1, tick(), SLOW, 0.4, ["warning_zone"]),
        (2.3, tick(), SLOW, 0.4, ["warning_zone"]),  # beyond clear_time: only ticks in window
        (2.45, tick(), SLOW, 0.4, ["warning_zone"]),
    ], config=config, state=warmed(config, until=1.9)[0])


def test_clearing_reasons_keep_the_cause_they_wait_for():
    state, _ = step(warmed()[0], frame(1.1, warn("W1", 0.5)), 1.1, MANUAL)
    _s, cmd = step(state, frame(1.2), 1.2, MANUAL)
    assert [(r.code, r.zone_id) for r in cmd.reasons] == [("warning_zone", "W1"),
                                                          ("clearing", None)]
    # latched: the cause is history, said by the latch (with its zone), never as holding now
    state, _ = step(warmed()[0], frame(1.1, prot("Z1")), 1.1, MANUAL)
    _s, cmd = step(state, frame(1.2), 1.2, MANUAL)
    assert [(r.code, r.zone_id) for r in cmd.reasons] == [("latched", "Z1"), ("clearing", None)]


def test_each_latch_has_its_own_nonce_and_a_reset_must_name_it():
    """A reset naming another latch (an earlier one, or one of an earlier run) is refused as
    stale before anything else is judged, whatever its age; one naming no latch too."""
    state, first = step(warmed()[0], frame(1.1, prot(), latch_nonce="n-a"), 1.1, MANUAL)
    assert first.latched_by.nonce == "n-a" and state.latches == 1
    state, _ = step(state, frame(1.2, latch_nonce="n-b"), 1.2, MANUAL)
    assert state.latched_by.nonce == "n-a"  # a latch keeps its nonce
    for t in (1.6, 2.0, 2.3):
        state, _ = step(state, frame(t), t, MANUAL)

    def ask(t, latch):
        return step(state, frame(t, reset_request=ResetRequest("op", t, "r", latch=latch)),
                    t, MANUAL)[1]

    stale = ask(2.4, "n-old")
    assert stale.state == STOP and stale.latched and not stale.reset.accepted
    assert stale.reset.message.startswith("refused: stale latch nonce 'n-old': the STOP "
                                          "latched now has nonce 'n-a'")
    assert "names no latch nonce" in ask(2.4, "").reset.message
    assert ask(2.4, "n-a").reset.accepted
    # released, then a new latch: new nonce (from the caller, else latch-<serial>)
    state, _ = step(state, frame(2.4, reset_request=ResetRequest("op", 2.4, "r", latch="n-a")),
                    2.4, MANUAL)
    for t in (2.5, 3.5, 3.6):
        state, _ = step(state, frame(t), t, MANUAL)
    state, second = step(state, frame(3.7, prot()), 3.7, MANUAL)
    assert second.latched_by.nonce == "latch-2" and state.latches == 2
    state, _ = step(state, frame(3.8), 3.8, MANUAL)
    for t in (4.2, 4.6, 4.9):
        state, _ = step(state, frame(t), t, MANUAL)
    late = step(state, frame(5.0, reset_request=ResetRequest("op", 5.0, "r2", latch="n-a")),
                5.0, MANUAL)[1]
    assert not late.reset.accepted and "stale latch nonce 'n-a'" in late.reset.message
    # a stale nonce is named even while a cause holds (it is the first thing wrong)
    held = step(state, frame(5.0, prot(), reset_request=ResetRequest("op", 5.0, "r3",
                                                                     latch="n-a")), 5.0, MANUAL)[1]
    assert "stale latch nonce 'n-a'" in held.reset.message
