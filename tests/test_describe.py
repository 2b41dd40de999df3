"""One description per command that never contradicts itself, in the operator's clock: the
latch's cause, what holds now, and whether a reset is possible (``Command.describe``), and the
service's command log line made of that one description."""

from __future__ import annotations

from datetime import datetime

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from monitor.policy import (
    RUN_CLEAR,
    SLOW_ACTIVE,
    STOP_ACTIVE,
    PolicyConfig,
    initial_state,
    step,
)
from monitor.service.log import command_fields
from monitor.timetext import video_time, wall_clock
from tests.policy_kit import CONFIGS, _inputs, frame, lost, reset, run, sequences, warmed

MANUAL = PolicyConfig()


def check_description(cmd) -> None:
    text = cmd.describe()
    causes = [r for r in cmd.reasons if r.code not in ("clearing", "latched")]
    if cmd.latched:
        assert text.startswith("STOP latched"), text
        if cmd.phase == STOP_ACTIVE:  # a STOP cause holds: a reset would be refused
            assert "reset possible" not in text and "holding now: " in text, text
            held = text.split("holding now: ", 1)[1]
            assert all(r.message in held for r in causes), text
        if cmd.reset_possible:  # nothing holds: no cause is listed as holding
            assert text.endswith("reset possible") and "holding" not in text, text
            after_latch = text.split(f" at {cmd.latched_by.at:.1f} s", 1)[1]
            assert not any(r.message in after_latch for r in cmd.reasons), text
    else:
        assert "latched" not in text and "reset" not in text, text
    if cmd.phase == RUN_CLEAR:
        assert text == "RUN"
    elif cmd.phase in (STOP_ACTIVE, SLOW_ACTIVE) and not cmd.latched:
        assert "clearing" not in text and "was:" not in text, text
    elif cmd.phase not in (STOP_ACTIVE, SLOW_ACTIVE) and causes and not cmd.latched:
        assert "clearing" in text and "(was: " in text, text  # past causes are said as past


@settings(max_examples=150, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(config=st.sampled_from(CONFIGS), sequence=sequences)
def test_description_never_contradicts_itself_in_any_phase(config, sequence):
    state = initial_state()
    now = 0.0
    phases = set()
    for s in sequence:
        now = round(now + s.dt, 6)
        state, cmd = step(state, _inputs(s, now), now, config)
        phases.add(cmd.phase)
        check_description(cmd)


def test_description_over_a_latch_lost_person_then_reset_possible():
    _state, cmds = run([
        (8.2, frame(8.2, lost()), "STOP", 0.0, ["person_lost", "latched"]),
        (8.3, frame(8.3, lost()), "STOP", 0.0, ["person_lost"]),
        (8.4, frame(8.4), "STOP", 0.0, ["latched"]),  # seen leaving: the hold ended
        (9.6, frame(9.6), "STOP", 0.0, ["latched"]),
        (9.7, frame(9.7, reset_request=reset(9.7)), "RUN", 1.0, []),
    ], state=warmed(until=8.1)[0])
    for cmd in cmds:
        check_description(cmd)
    assert cmds[3].describe() == ("STOP latched by person 3 lost inside robot-protective at "
                                  "8.2 s; no STOP cause now (clear for 1.3 s): reset possible")


def _latched_reset_possible():
    """A person lost inside latched the STOP, then was seen leaving: reset possible, while
    the reasons still carry the cause that held before (``hold_reasons``)."""
    state, _ = warmed(until=1058.0)
    for t in (1059.9, 1060.0):
        state, _cmd = step(state, frame(t, lost(since=1059.8)), t, MANUAL)
    state, cmd = step(state, frame(1060.1), 1060.1, MANUAL)
    assert cmd.reset_possible
    return cmd


def test_service_log_line_is_one_description_in_wall_clock_time():
    cmd = _latched_reset_possible()
    assert any("lost inside" in r.message for r in cmd.reasons)  # the old line listed it
    wall = 1_700_000_000.0
    fields = command_fields(cmd, wall_clock(lambda: 1062.1, lambda: wall))
    assert "reasons" not in fields  # no second list beside the description
    line = " ".join(f"{k}={v}" for k, v in fields.items())
    assert "lost inside" in line and line.count("lost inside") == 1  # the latch's cause
    assert "holding" not in line and line.endswith("reset possible")
    assert fields["reset_possible"] is True
    stamp = datetime.fromtimestamp(wall - 2.2).strftime("%H:%M:%S")  # latched at 1059.9
    assert f"at {stamp};" in fields["describe"]
    assert "1059" not in line and "1060" not in line  # no monotonic seconds for an operator


def test_wall_clock_says_how_long_ago_for_old_times():
    when = wall_clock(lambda: 5000.0, lambda: 1_700_000_000.0)
    stamp = datetime.fromtimestamp(1_700_000_000.0 - 600).strftime("%H:%M:%S")
    assert when(4400.0) == f"{stamp} (10 min ago)"
    assert "ago" not in when(4990.0)


def test_replay_describes_in_video_seconds():
    from monitor.replay.video import describe

    cmd = _latched_reset_possible()
    assert describe(cmd) == cmd.describe(video_time)
    assert "at 1059.9 s of the video" in describe(cmd)
