"""The robot-side adapters' pure decisions (monitor/adapters/): the Modbus register values, the
OPC UA variable values and the snapshot every adapter shows, beyond the stale limits
(tests/test_adapter_stale_limits.py). Mutation testing (benchmarks/mutation.py) found what
these pin down."""

from __future__ import annotations

import time
from datetime import UTC, datetime

from monitor.adapters import modbus_map as mm
from monitor.adapters import opcua as ua
from monitor.adapters import ros2
from monitor.adapters.snapshot import SafetySnapshot, snapshot_of
from monitor.wire.consumer import Verdict

NOW = 1000.0


def snap(state: str = "RUN", scale: float = 1.0, reasons: list | None = None, age_s: float = 0.05,
         code: str = "", seq: int | None = 5, **body) -> SafetySnapshot:
    made = NOW - age_s
    cmd = {"state": state, "speed_scale": scale, "reasons": reasons or [], **body}
    return snapshot_of(Verdict(state, scale, "", seq, cmd, code), made, time.time(), 7,
                       made - 0.01, ("cam0", "cam1"))


def raw(state: str = "RUN", scale: float = 1.0, *, mono: float = NOW - 0.0625, **over
        ) -> SafetySnapshot:
    """A snapshot as the follower makes it, every field chosen (no snapshot_of rules); made
    62.5 ms before ``NOW`` (binary-exact ages: the registers truncate to whole ms)."""
    fields = dict(state=state, speed_scale=scale, latched=False, reset_possible=False,
                  reason_code="", reason="", zone_id=None, seq=5, age_ms=10.0, counter=7,
                  mono=mono, wall=1.7e9)
    return SafetySnapshot(**{**fields, **over})


# --- the Modbus register map (monitor/adapters/modbus_map.py, docs/plc.md) -------------------

A = mm.ADDRESS


def test_before_any_snapshot_every_register_reads_stop_no_command():
    st = mm.AdapterState(reset_result=2, reset_count=70_000, case=3, write_errors=65_537,
                         case_result=4, case_count=65_536 + 9)
    regs = mm.render(None, NOW, st)
    assert len(regs) == mm.SIZE == 35
    expected = [0] * mm.SIZE
    expected[A["reason"]] = mm.REASON_CODES["no_command"]
    expected[A["command_age_ms"]] = expected[A["snapshot_age_ms"]] = 0xFFFF
    expected[A["status"]] = 0b10001  # stale (nothing to show) and no command
    expected[A["map_version"]] = mm.MAP_VERSION
    expected[A["reset_result"]], expected[A["reset_count"]] = 2, 70_000 & 0xFFFF
    expected[A["case_echo"]], expected[A["write_errors"]] = 3, 1
    expected[A["case_result"]], expected[A["case_count"]] = 4, 9
    assert regs == expected


def test_a_fresh_slow_shows_every_field_of_its_snapshot():
    st = mm.AdapterState(zones=("W1", "W2"), cameras=("cam0", "cam1", "cam2"),
                         case_sets=("a", "b"))
    s = raw("SLOW", 0.3, latched=True, reset_possible=True, reason_code="warning_zone",
            zone_id="W2", seq=70_001, age_ms=40.0, counter=65_536 + 3,
            faults=("camera_moved", "no_such_fault", "detector_error"),
            cameras={"cam0": True, "cam1": False, "cam2": True}, zone_sets=("b", "a"))
    regs = mm.render(s, NOW, st)
    assert regs[A["state"]] == 1 and regs[A["speed_scale"]] == 300
    assert regs[A["latched"]] == 1 and regs[A["reset_possible"]] == 1
    assert regs[A["reason"]] == mm.REASON_CODES["warning_zone"] == 30
    assert regs[A["zone"]] == 2  # the 1-based position in --zone
    assert regs[A["seq"]] == 70_001 & 0xFFFF and regs[A["heartbeat"]] == 3
    assert regs[A["command_age_ms"]] == 102  # 40 ms old when made, made 62.5 ms ago
    assert regs[A["snapshot_age_ms"]] == 62
    assert regs[A["faults"]] == (1 << 3) | (1 << 6) | (1 << 15)
    assert regs[A["cameras_ok"]] == 0b101
    assert regs[A["case_sets"]] == 0b11
    assert regs[A["status"]] == 0 and regs[A["map_version"]] == mm.MAP_VERSION


def test_a_stale_snapshot_keeps_only_what_says_how_old_it_is():
    st = mm.AdapterState(stale_s=0.25, zones=("P",), cameras=("cam0",), case_sets=("a",))
    s = raw("RUN", 1.0, mono=NOW - 0.375, latched=True, reset_possible=True, zone_id="P",
            reason_code="warning_zone", faults=("camera_lost",), cameras={"cam0": True},
            zone_sets=("a",), seq=9, counter=11, age_ms=5.0)
    regs = mm.render(s, NOW, st)
    for name in ("state", "speed_scale", "reset_possible", "zone", "faults", "cameras_ok",
                 "case_sets"):
        assert regs[A[name]] == 0, name
    assert regs[A["reason"]] == mm.REASON_CODES["adapter_stale"]
    assert regs[A["status"]] == 1
    # the last known latch, seq, heartbeat and ages are still shown
    assert regs[A["latched"]] == 1 and regs[A["seq"]] == 9 and regs[A["heartbeat"]] == 11
    assert regs[A["command_age_ms"]] == 380 and regs[A["snapshot_age_ms"]] == 375


def test_exactly_the_stale_limit_is_still_fresh_and_an_age_of_nothing_reads_zero():
    st = mm.AdapterState(stale_s=0.25)
    at_limit = mm.render(raw(mono=NOW - 0.25), NOW, st)  # binary-exact: 0.25 s old
    assert at_limit[A["state"]] == 2 and at_limit[A["status"]] == 0
    now = mm.render(raw(mono=NOW, age_ms=0.0), NOW, st)
    assert now[A["snapshot_age_ms"]] == 0 and now[A["command_age_ms"]] == 0
    assert mm.render(raw(mono=NOW, age_ms=0.9), NOW, st)[A["command_age_ms"]] == 0
    # ages in whole ms, truncated: 999.02 ms reads 999 (+10 ms of command age: 1009)
    almost = mm.render(raw(mono=NOW - (1 - 2**-10)), NOW, mm.AdapterState(stale_s=2.0))
    assert almost[A["snapshot_age_ms"]] == 999 and almost[A["command_age_ms"]] == 1009
    # a snapshot from the future (a clock glitch) is age 0, never negative or wrapped
    ahead = mm.render(raw(mono=NOW + 0.1, age_ms=None), NOW, st)
    assert ahead[A["snapshot_age_ms"]] == 0 and ahead[A["command_age_ms"]] == 0xFFFF
    # ages beyond 65.535 s saturate (a PLC never sees a long age wrap to a short one)
    old = mm.render(raw(mono=NOW - 0.1, age_ms=1e9), NOW, mm.AdapterState(stale_s=1.0))
    assert old[A["command_age_ms"]] == 0xFFFF


def test_a_stop_reads_speed_zero_whatever_its_scale_and_run_reads_per_mille():
    st = mm.AdapterState()
    assert mm.render(raw("STOP", 0.5), NOW, st)[A["speed_scale"]] == 0
    assert mm.render(raw("RUN", 0.25), NOW, st)[A["speed_scale"]] == 250
    assert mm.render(raw("RUN", 0.0005), NOW, st)[A["speed_scale"]] == 0  # rounded, not 1


def test_the_zone_register_none_listed_and_unlisted():
    st = mm.AdapterState(zones=("P1", "P2"))
    assert mm.render(raw(zone_id="P1"), NOW, st)[A["zone"]] == 1
    assert mm.render(raw(zone_id="X"), NOW, st)[A["zone"]] == 0xFFFF
    assert mm.render(raw(zone_id=None), NOW, st)[A["zone"]] == 0
    assert mm.render(raw(zone_id=""), NOW, st)[A["zone"]] == 0


def test_an_unknown_reason_code_reads_999():
    assert mm.render(raw(reason_code="brand_new"), NOW, mm.AdapterState())[A["reason"]] == 999


def test_each_status_bit_alone():
    fresh = raw()
    for flag, bit in (("watchdog_expired", 1), ("inputs_enabled", 2), ("unauthenticated", 3)):
        regs = mm.render(fresh, NOW, mm.AdapterState(**{flag: True}))
        assert regs[A["status"]] == 1 << bit, flag
    no_seq = mm.render(raw(seq=None), NOW, mm.AdapterState())
    assert no_seq[A["status"]] == 1 << 4 and no_seq[A["seq"]] == 0
    # bits add up: inputs on, no verified command yet, stale
    both = mm.render(raw(seq=None, mono=NOW - 1.0), NOW, mm.AdapterState(inputs_enabled=True))
    assert both[A["status"]] == 0b10101


def test_cameras_ok_counts_the_first_16_cameras_only():
    cams = tuple(f"c{i}" for i in range(18))
    regs = mm.render(raw(cameras=dict.fromkeys(cams, True)), NOW, mm.AdapterState(cameras=cams))
    assert regs[A["cameras_ok"]] == 0xFFFF
    one = mm.render(raw(cameras={"c17": True, "c1": True}), NOW, mm.AdapterState(cameras=cams))
    assert one[A["cameras_ok"]] == 0b10


def test_fault_and_set_bits_each_position_and_the_other_bit():
    for i, name in enumerate(mm.FAULT_BITS):
        assert mm.render(raw(faults=(name,)), NOW, mm.AdapterState())[A["faults"]] == 1 << i
    assert mm.render(raw(faults=("x", "y")), NOW, mm.AdapterState())[A["faults"]] == 1 << 15
    sets = tuple(f"s{i}" for i in range(17))
    st = mm.AdapterState(case_sets=sets)
    for i in range(15):
        assert mm.render(raw(zone_sets=(sets[i],)), NOW, st)[A["case_sets"]] == 1 << i
    # the 16th set and one not listed: bit 15 ("other")
    assert mm.render(raw(zone_sets=(sets[15],)), NOW, st)[A["case_sets"]] == 1 << 15
    assert mm.render(raw(zone_sets=("zz", "s2")), NOW, st)[A["case_sets"]] == (1 << 15) | 4


def test_written_registers_read_back_what_the_plc_wrote():
    st = mm.AdapterState(written={A["plc_watchdog"]: 1234, A["monitoring_case"]: 2})
    regs = mm.render(raw(), NOW, st)
    assert regs[A["plc_watchdog"]] == 1234 and regs[A["monitoring_case"]] == 2
    assert regs[A["reset_request"]] == 0


# --- writes (check_write) ----------------------------------------------------------------------


def write(address, values, *, client=True, inputs=True, case_limit=None):
    return mm.check_write(address, values, allowed_client=client, inputs_enabled=inputs,
                          case_limit=case_limit)


def test_writes_in_range_to_writable_registers_are_accepted():
    wd, rr, mc = A["plc_watchdog"], A["reset_request"], A["monitoring_case"]
    assert write(wd, [0xFFFF]) is None and write(wd, [0]) is None
    assert write(rr, [1]) is None and write(mc, [255]) is None
    assert write(wd, [7, 1, 255]) is None  # 32..34 in one request
    assert write(wd, [9], inputs=False) is None  # the watchdog needs no --inputs
    assert write(mc, [3], case_limit=3) is None and write(mc, [0], case_limit=0) is None


def test_a_read_only_register_or_switched_off_inputs_is_an_illegal_address():
    wd, rr, mc = A["plc_watchdog"], A["reset_request"], A["monitoring_case"]
    assert write(A["state"], [2]) == mm.ILLEGAL_ADDRESS
    assert write(31, [1]) == mm.ILLEGAL_ADDRESS  # a gap of the map
    assert write(mc, [1, 1]) == mm.ILLEGAL_ADDRESS  # runs past the last register
    assert write(wd - 1, [1, 1]) == mm.ILLEGAL_ADDRESS  # starts before the first writable
    assert write(rr, [1], inputs=False) == mm.ILLEGAL_ADDRESS
    assert write(mc, [1], inputs=False) == mm.ILLEGAL_ADDRESS
    assert write(wd, [1, 1], inputs=False) == mm.ILLEGAL_ADDRESS  # the second touches an input
    # the address is judged before the client: a PLC learns nothing of the allow-list
    assert write(A["state"], [2], client=False) == mm.ILLEGAL_ADDRESS


def test_a_client_off_the_allow_list_is_an_illegal_function_even_with_a_bad_value():
    assert write(A["plc_watchdog"], [1], client=False) == mm.ILLEGAL_FUNCTION
    assert write(A["reset_request"], [9], client=False) == mm.ILLEGAL_FUNCTION


def test_values_out_of_range_or_not_integers_are_illegal_values():
    wd, rr, mc = A["plc_watchdog"], A["reset_request"], A["monitoring_case"]
    assert write(wd, [0x10000]) == mm.ILLEGAL_VALUE
    assert write(wd, [-1]) == mm.ILLEGAL_VALUE
    assert write(rr, [2]) == mm.ILLEGAL_VALUE
    assert write(mc, [256]) == mm.ILLEGAL_VALUE
    assert write(mc, [4], case_limit=3) == mm.ILLEGAL_VALUE
    assert write(mc, [1], case_limit=0) == mm.ILLEGAL_VALUE
    assert write(rr, [True]) == mm.ILLEGAL_VALUE and write(wd, [1.0]) == mm.ILLEGAL_VALUE
    assert write(wd, [1, 2, 3]) == mm.ILLEGAL_VALUE  # all or nothing: 2 is no reset request
    assert write(wd, [1, 1, 256]) == mm.ILLEGAL_VALUE


# --- the OPC UA variables (monitor/adapters/opcua.py, docs/opcua.md) --------------------------

SSM = "SafetyStateManagement"


def test_the_variables_show_every_field_of_a_fresh_snapshot():
    s = raw("SLOW", 0.4, latched=True, reset_possible=True, reason_code="warning_zone",
            reason="person in W1", zone_id="W1", seq=12, age_ms=30.0, counter=2**32 + 5,
            wall=1.7e9, faults=("camera_moved",), cameras={"cam0": True, "cam1": False},
            cell="c1", instance="m1", zone_hash="h1")
    v = ua.values_of(s, ("cam0", "cam1", "cam9"))
    assert v == {
        "State": 1, "StateName": "SLOW", "SpeedScale": 0.4, "Latched": True,
        "ResetPossible": True, "ReasonCode": "warning_zone", "Reason": "person in W1",
        "ZoneId": "W1", "Seq": 12, "Heartbeat": 5, "CommandAgeMs": 30.0,
        "SnapshotTime": datetime.fromtimestamp(1.7e9, UTC), "Faults": ["camera_moved"],
        "CameraIds": ["cam0", "cam1", "cam9"], "CamerasOk": [True, False, False],
        "CameraOk": False, "Cell": "c1", "MonitorInstance": "m1", "ZoneHash": "h1",
        f"{SSM}.VisionSafetyTriggered": True,
        f"{SSM}.VisionSafetyInformation": "SLOW: warning_zone: person in W1"}
    assert set(v) == {x.name for x in ua.VARIABLES}


def test_a_clean_run_is_camera_ok_and_not_triggered():
    v = ua.values_of(raw(seq=None, age_ms=None, cameras={"cam0": True}), ("cam0",))
    assert v["CameraOk"] is True and v["CamerasOk"] == [True]
    assert v[f"{SSM}.VisionSafetyTriggered"] is False
    assert v[f"{SSM}.VisionSafetyInformation"] == "RUN: clear"
    assert v["Seq"] == -1 and v["CommandAgeMs"] == -1.0 and v["ZoneId"] == ""
    # one fault, even with every camera ok, is not CameraOk
    assert ua.values_of(raw(faults=("detector_error",), cameras={"cam0": True}),
                        ("cam0",))["CameraOk"] is False
    # the information text is cut at 1000 characters
    long = ua.values_of(raw(reason="x" * 2000), ())[f"{SSM}.VisionSafetyInformation"]
    assert len(long) == 1000 and long.startswith("RUN: clear: xxx")


def test_an_override_says_nothing_about_the_cameras():
    for code in sorted(ua.OVERRIDES):
        v = ua.values_of(raw("STOP", 0.0, reason_code=code, cameras={"cam0": True}), ("cam0",))
        assert v["CamerasOk"] == [False] and v["CameraOk"] is False, code


def test_stop_values_keep_what_says_how_old_the_rest_is():
    fresh = ua.values_of(raw("RUN", 1.0, latched=True, zone_id="W", seq=4, counter=9,
                             cameras={"a": True, "b": True}), ("a", "b"))
    stop = ua.stop_values(fresh, "adapter_stale", "stuck")
    assert stop == {**fresh, "State": 0, "StateName": "STOP", "SpeedScale": 0.0,
                    "ResetPossible": False, "ReasonCode": "adapter_stale", "Reason": "stuck",
                    "ZoneId": "", "CamerasOk": [False, False], "CameraOk": False,
                    f"{SSM}.VisionSafetyTriggered": True,
                    f"{SSM}.VisionSafetyInformation": "STOP: adapter_stale: stuck"}
    assert fresh["State"] == 2  # the values handed in are not changed


def test_before_any_snapshot_the_server_shows_stop_no_command():
    before = datetime.now(UTC)
    v = ua.initial_values(("cam0", "cam1"))
    assert before <= v.pop("SnapshotTime") <= datetime.now(UTC)
    assert v == {"Latched": False, "Seq": -1, "Heartbeat": 0, "CommandAgeMs": -1.0,
                 "Faults": [], "CameraIds": ["cam0", "cam1"], "Cell": "",
                 "MonitorInstance": "", "ZoneHash": "", "State": 0, "StateName": "STOP",
                 "SpeedScale": 0.0, "ResetPossible": False, "ReasonCode": "no_command",
                 "Reason": "adapter started: no command yet", "ZoneId": "",
                 "CamerasOk": [False, False], "CameraOk": False,
                 f"{SSM}.VisionSafetyTriggered": True,
                 f"{SSM}.VisionSafetyInformation":
                     "STOP: no_command: adapter started: no command yet"}


def test_next_values_writes_each_tick_once_and_a_stale_spell_once():
    cams = ("cam0",)
    shown = ua.initial_values(cams)
    assert ua.next_values(None, NOW, 0.25, shown, None, cams) is None  # the STOP stands
    s = raw(counter=3, cameras={"cam0": True})
    first = ua.next_values(s, NOW, 0.25, shown, None, cams)
    assert first == ua.values_of(s, cams)
    assert ua.next_values(s, NOW, 0.25, first, 3, cams) is None  # this tick is shown
    assert ua.next_values(s, NOW, 0.25, first, 2, cams) == first
    # exactly at the limit: still the verdict (binary-exact 0.25 s)
    assert ua.next_values(raw(mono=NOW - 0.25, counter=4), NOW, 0.25, first, 3, cams)["State"] \
        == 2
    late = ua.next_values(s, NOW + 0.25, 0.25, first, 3, cams)  # 0.3125 s old
    assert late == ua.stop_values(first, "adapter_stale",
                                  "the adapter's loop handed over no snapshot for 250 ms")
    assert ua.next_values(s, NOW + 1, 0.25, late, 3, cams) is None  # shown once a spell
    assert ua.next_values(s, NOW + 2, 1.0, first, 3, cams)["Reason"] == \
        "the adapter's loop handed over no snapshot for 1000 ms"
    # a STOP shown for another reason is replaced by the stale STOP
    other = ua.stop_values(first, "ttl", "silence")
    assert ua.next_values(s, NOW + 1, 0.25, other, 3, cams)["ReasonCode"] == "adapter_stale"


def test_the_stale_check_is_the_documented_limit_not_a_multiple():
    assert not ua.stale(raw(mono=NOW - 0.25), NOW, 0.25)
    assert ua.stale(raw(mono=NOW - 0.25 - 2**-10), NOW, 0.25)
    assert ua.stale(raw(mono=float("nan")), NOW, 0.25)
    assert not ua.stale(raw(mono=NOW + 1.0), NOW, 0.25)  # from the future: not stale (age < 0)


def test_the_state_goes_first_when_safer_and_last_when_less_safe():
    cams = ("cam0",)
    run = ua.values_of(raw("RUN", 1.0, counter=1, cameras={"cam0": True}), cams)
    slow = ua.values_of(raw("SLOW", 0.5, counter=1, cameras={"cam0": True}), cams)
    slower = ua.values_of(raw("SLOW", 0.25, counter=1, cameras={"cam0": True}), cams)
    state = ["State", "StateName", "SpeedScale", f"{SSM}.VisionSafetyTriggered"]
    assert ua.write_order(run, slow) == [*state, f"{SSM}.VisionSafetyInformation"]
    assert ua.write_order(slow, run) == [f"{SSM}.VisionSafetyInformation", *state]
    assert ua.write_order(slow, slower) == ["SpeedScale"]
    assert ua.write_order(slower, slow) == ["SpeedScale"]
    assert ua.write_order(run, run) == []
    # the same state at a lower scale is safer: its scale goes first
    bumped = {**slower, "Reason": "r"}
    assert ua.write_order(slow, bumped) == ["SpeedScale", "Reason"]
    assert ua.write_order(slower, {**slow, "Reason": "r"}) == ["Reason", "SpeedScale"]
    # nothing shown before: only a STOP at scale 0 counts as safer
    assert ua.write_order({}, ua.initial_values(cams))[:5] == [*state, "Latched"]
    assert ua.write_order({}, run)[-4:] == state
    slow_zero = ua.values_of(raw("SLOW", 0.0, counter=1), cams)
    assert ua.write_order({}, slow_zero)[-4:] == state  # SLOW at 0 is no safer than STOP


# --- the verdict every adapter shows (snapshot_of) and the ROS 2 speed override ---------------


def test_a_followed_command_becomes_a_snapshot_field_by_field():
    cmd = {"state": "SLOW", "speed_scale": 0.5, "latched": True, "reset_possible": True,
           "cell": "c1", "instance": "m1", "config_hash": "h1", "zone_sets": ["a", 2],
           "reasons": [
               "not a dict",
               {"code": "muted", "message": "zone W2 muted"},  # a note: never the cause
               {"code": "warning_zone", "zone_id": "W1", "message": "person in W1"},
               {"code": "fault", "fault": "camera_moved", "source": "cam1", "message": "moved"},
               {"code": "fault", "fault": "detector_error", "message": "no source"},
               {"code": "x", "source": "cam0", "message": "a source without a fault"}]}
    s = snapshot_of(Verdict("SLOW", 0.5, "", 41, cmd), 10.0, 1.7e9, 3, 9.75,
                    ("cam0", "cam1"))
    assert s == SafetySnapshot(
        state="SLOW", speed_scale=0.5, latched=True, reset_possible=True,
        reason_code="warning_zone",
        reason="zone W2 muted; person in W1; moved; no source; a source without a fault",
        zone_id="W1", seq=41, age_ms=250.0, counter=3, mono=10.0, wall=1.7e9,
        faults=("camera_moved", "detector_error"), cameras={"cam0": True, "cam1": False},
        cell="c1", instance="m1", zone_hash="h1", zone_sets=("a", "2"))


def test_a_clean_run_has_no_reason_code_no_zone_and_its_own_scale():
    s = snapshot_of(Verdict("RUN", 1.0, "", 2, {"reasons": [{"code": "muted"}]}), 5.0, 0.0,
                    1, 5.0)
    assert s.reason_code == "" and s.zone_id is None and s.speed_scale == 1.0
    assert s.reason == ""  # a reason without a message adds an empty one
    assert s.age_ms == 0.0 and not s.latched and not s.reset_possible and s.zone_sets == ()
    assert s.cell == s.instance == s.zone_hash == ""
    # reasons or zone sets that are no lists are read as none
    odd = snapshot_of(Verdict("RUN", 1.0, "", 2, {"reasons": {"code": "x"}, "zone_sets": "ab"}),
                      5.0, 0.0, 1, None)
    assert odd.reason_code == "" and odd.reason == "" and odd.zone_sets == ()
    assert odd.age_ms is None  # no command received yet: no age
    for junk in (5, None, "text", 1.5):  # whatever JSON gives that is no list
        bad = snapshot_of(Verdict("RUN", 1.0, "", 2, {"reasons": junk, "zone_sets": junk}),
                          5.0, 0.0, 1, None)
        assert bad.reason == "" and bad.zone_sets == () and bad.state == "RUN", junk
    assert snapshot_of(Verdict("RUN", 1.0, "", None, None), 5.0, 0.0, 1, 4.0).age_ms is None
    # a reason whose zone is empty names no zone
    empty_zone = {"reasons": [{"code": "warning_zone", "zone_id": ""}]}
    assert snapshot_of(Verdict("SLOW", 0.5, "", 2, empty_zone), 5.0, 0.0, 1, 5.0).zone_id is None


def test_an_override_keeps_the_last_latch_but_no_reset_zone_or_sets():
    cmd = {"latched": True, "reset_possible": True, "zone_sets": ["a"], "reasons": [
        {"code": "protective_zone", "zone_id": "P", "message": "person", "fault": "f",
         "source": "cam0"}]}
    s = snapshot_of(Verdict("STOP", 0.0, "silence for 300 ms", 8, cmd, "ttl"), 2.0, 1e9, 4, 1.5,
                    ("cam0", "cam1"))
    assert s.state == "STOP" and s.speed_scale == 0.0
    assert s.latched and not s.reset_possible
    assert s.reason_code == "ttl" and s.reason == "silence for 300 ms"
    assert s.zone_id is None and s.zone_sets == () and s.faults == ()
    assert s.cameras == {"cam0": False, "cam1": False} and s.age_ms == 500.0


def test_a_stop_verdict_carries_scale_zero_and_edge_scales_stay():
    assert snapshot_of(Verdict("STOP", 0.5, ""), 1.0, 0.0, 1, None).speed_scale == 0.0
    assert snapshot_of(Verdict("SLOW", 0.0, ""), 1.0, 0.0, 1, None).state == "SLOW"
    one = snapshot_of(Verdict("RUN", 1.0, ""), 1.0, 0.0, 1, None)
    assert one.state == "RUN" and one.speed_scale == 1.0
    inf = snapshot_of(Verdict("RUN", float("inf"), ""), 1.0, 0.0, 1, None)
    assert inf.state == "STOP" and inf.speed_scale == 0.0


def test_the_ros_speed_override_is_the_verdicts_scale_in_range():
    assert ros2.speed_override(raw("RUN", 1.0)) == 1.0
    assert ros2.speed_override(raw("SLOW", 0.25)) == 0.25
    assert ros2.speed_override(raw("SLOW", 0.0)) == 0.0
    assert ros2.speed_override(raw("RUN", 1.0 + 1e-9)) == 0.0
    assert ros2.speed_override(raw("SLOW", -1e-9)) == 0.0
    assert ros2.speed_override(raw("STOP", 0.5)) == 0.0
    assert type(ros2.speed_override(raw("RUN", 1))) is float  # CDR float64, never an int
