"""`monitor status` as text (monitor/cli/status_text.py): what an operator reads of a status
answer, from the real policy's commands; a broken or hostile answer never reads as clear."""

from __future__ import annotations

import time

import pytest

from monitor.cli.status_text import duration, status_text
from monitor.policy import PolicyConfig, step
from tests.policy_kit import frame, prot, warmed

STARTED = 1_700_000_000.0


def _latched_clear_command() -> dict:
    """The real policy: person 1 entered cam0-stop at 100.0, left; latched, reset possible."""
    state, _ = warmed(until=99.9)
    state, _ = step(state, frame(100.0, prot("cam0-stop", person=1)), 100.0, PolicyConfig())
    _state, cmd = step(state, frame(101.5), 101.5, PolicyConfig())
    return cmd.to_dict()


def _status(**over) -> dict:
    status = {
        "schema": "workcell.safety.status/1", "cell": "cell1", "role": "", "instance": "mon-1",
        "boot": "0123456789abcdef", "config_hash": "abc123def", "uptime_s": 3725.0,
        "started_wall": STARTED, "wall": STARTED + 3725.0, "state": "STOP",
        "command": _latched_clear_command(), "latch": "n1", "signed": True,
        "other_monitors": [], "fps": 9.5, "inference_ms": 21.25,
        "cameras": [{"id": "cam0", "connected": True, "dropped": 3, "reconnects": 0,
                     "last_error": None, "fps": 9.5},
                    {"id": "cam1", "connected": False, "dropped": 0, "reconnects": 2,
                     "last_error": "rtsp timeout", "fps": 0.0}],
        "muted": [{"zone": "robot-warning", "operator": "anna", "as": "off",
                   "speed_scale": None, "until": "14:03:12", "until_wall": STARTED + 4000}],
        "zones_file": "/etc/workcell-monitor/cell.yaml",
        "commissioned": {"checksum": "feedbeefcafe0123456789", "by": "anna", "matches": True},
    }
    return {**status, **over}


def test_the_summary_names_command_latch_reasons_cameras_mutes_zones_and_commissioning():
    text = status_text(_status())
    lines = text.splitlines()
    assert lines[0].startswith("monitor mon-1 (cell cell1), boot 01234567, up 1 h 02 min")
    assert "commands signed" in lines[0]
    assert lines[1] == "command: STOP, LATCHED: reset possible"
    assert lines[2].startswith("  latched [cam0-stop]: latched by person 1 in cam0-stop at ")
    assert lines[2].endswith("cell clear, reset possible")
    assert "faults: none" in lines
    assert "cameras (9.5 fps, inference 21.2 ms):" in lines
    assert "  cam0: connected, 9.5 fps, dropped 3" in lines
    assert "  cam1: NOT CONNECTED: rtsp timeout" in lines
    assert "  robot-warning as off by anna until 14:03:12" in lines
    assert "zones: /etc/workcell-monitor/cell.yaml, config hash abc123def" in lines
    assert "commissioned: yes, checksum feedbeefcafe0123 by anna" in lines
    assert "WARNING" not in text and "{" not in text  # no JSON, nothing to warn about


def test_faults_zone_sets_a_refused_reset_and_warnings_are_said():
    command = {"state": "STOP", "speed_scale": 0.0, "latched": True, "reset_possible": False,
               "zone_sets": ["day", "night"],
               "reasons": [{"code": "fault", "message": "camera_lost: no frame for 2 s",
                            "fault": "camera_lost", "source": "cam1"},
                           {"code": "latched", "message": "STOP latched: waiting for an "
                            "operator reset"}]}
    text = status_text(_status(
        command=command, signed=False, other_monitors=["boot 77"], muted=[],
        without_reference=["cam1"],
        commissioned={"checksum": None, "matches": False, "reason": "zones changed"},
        last_reset={"operator": "bob", "accepted": False, "message": "refused: x",
                    "wall": STARTED}))
    lines = text.splitlines()
    assert "commands NOT SIGNED" in lines[0]
    assert lines[1] == "command: STOP, LATCHED: no reset until the causes clear"
    assert "faults: camera_lost (cam1)" in lines
    assert "zone sets in force: day, night (switching: their union applies)" in lines
    assert "muted zones: none" in lines
    assert "commissioned: NO (zones changed)" in lines
    differs = status_text({"commissioned": {"checksum": "ab", "matches": False,
                                            "differs": ["bus.operators_file"]}})
    assert "commissioned: NO (not commissioned: bus.operators_file differ from the record)" \
        in differs.splitlines()
    assert any(line.startswith("last reset: bob refused at ") for line in lines)
    assert "WARNING: other monitors answer for this cell: boot 77" in lines
    assert "WARNING: no reference image for cam1: glare and image conditions judged by the " \
        "model envelope's absolute limits only" in lines


@pytest.mark.parametrize("status", [
    pytest.param({}, id="empty"),
    pytest.param({"command": None, "state": "RUN"}, id="no-command-says-run"),
    pytest.param({"command": "RUN", "cameras": "x", "muted": 7, "uptime_s": "long",
                  "commissioned": [], "other_monitors": "y"}, id="wrong-types"),
    pytest.param({"command": {"state": "RUN", "reasons": [1, None, {"code": "x"}],
                              "speed_scale": float("nan"), "zone_sets": "a"}},
                 id="odd-reasons"),
])
def test_a_broken_answer_never_reads_as_clear_nor_fails(status):
    lines = status_text(status).splitlines()
    assert lines[0].startswith(f"monitor {status.get('instance', '?')} (cell ?)")
    if isinstance(status.get("command"), dict):
        assert lines[1] == "command: RUN" and "  (no reason)" not in lines  # as reported
        assert "  x: " in lines and "faults: none" in lines
    else:
        assert lines[1] == "command: STOP (no command decided yet)"
    assert "cameras: none reported yet" in lines and "muted zones: none" in lines
    assert "commissioned: unknown (not reported)" in lines


def test_durations_read_as_hours_minutes_seconds():
    assert [duration(s) for s in (0, 59.9, 61, 3599, 3600, 90000)] == [
        "0 s", "59 s", "1 min 01 s", "59 min 59 s", "1 h 00 min", "25 h 00 min"]
    assert duration(None) == duration(float("nan")) == duration(-1) == "?"


def test_the_start_time_is_local_wall_clock():
    stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(STARTED))
    assert f"(since {stamp})" in status_text(_status())
