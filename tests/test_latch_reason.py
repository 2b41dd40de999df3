"""Latched with the person gone (issue 32): every output says the latch's cause as a past event
with its wall-clock time ("latched by person 1 in cam0-stop at 12:00:03; cell clear, reset
possible"), never "person 1 in cam0-stop" beside reset possible. The real policy makes the
command; a real Modbus server with a pymodbus client and a real OPC UA server with an asyncua
client read it as a PLC and an operator panel would."""

from __future__ import annotations

import time
from datetime import datetime

import pytest
from asyncua.sync import Client

from monitor.adapters import modbus_map as mm
from monitor.adapters.modbus import ModbusOutput
from monitor.adapters.opcua import NAMESPACE, OpcUaOutput, OpcUaSettings, node_id
from monitor.adapters.snapshot import snapshot_of
from monitor.policy import PolicyConfig, Reason, step
from monitor.timetext import wall_clock
from monitor.wire.consumer import Verdict
from tests.helpers import free_port, wait_for
from tests.plc_kit import Plc
from tests.policy_kit import frame, prot, warmed, warn

MANUAL = PolicyConfig()
ZONES = ("cam0-warn", "cam0-stop")
# the monotonic time 100.0 is 12:00:03 local time; the clock reads 2 s later
LATCHED_AT = datetime(2024, 5, 6, 12, 0, 3).timestamp()
WHEN = wall_clock(lambda: 102.0, lambda: LATCHED_AT + 2.0)


def _latched_timeline(*later_hits):
    """Person 1 walks into cam0-stop at 100.0 (12:00:03) and leaves at 100.2; the commands
    while inside and after leaving (``later_hits`` in the frames after)."""
    state, _ = warmed(until=99.9)
    state, inside = step(state, frame(100.0, prot("cam0-stop", person=1)), 100.0, MANUAL, WHEN)
    state, still = step(state, frame(100.1, prot("cam0-stop", person=1)), 100.1, MANUAL, WHEN)
    state, left = step(state, frame(100.2, *later_hits), 100.2, MANUAL, WHEN)
    state, clear = step(state, frame(101.5, *later_hits), 101.5, MANUAL, WHEN)
    return inside, still, left, clear


def _messages(cmd) -> list[str]:
    return [r.message for r in cmd.reasons]


def test_while_inside_present_tense_after_leaving_a_past_event_with_its_time():
    inside, still, left, clear = _latched_timeline()
    for cmd in (inside, still):  # the person is inside: said as holding now
        assert cmd.latched and not cmd.reset_possible
        assert cmd.reasons[0] == Reason("protective_zone", "person 1 in cam0-stop",
                                        zone_id="cam0-stop", person=1, distance_m=0.0)
        assert "STOP latched: waiting for an operator reset" in _messages(cmd)
    for cmd in (left, clear):  # gone: the latch is the cause, as history with its time
        assert cmd.latched and cmd.reset_possible
        first = cmd.reasons[0]
        assert (first.code, first.zone_id, first.person) == ("latched", "cam0-stop", None)
        assert first.message == ("latched by person 1 in cam0-stop at 12:00:03; cell clear, "
                                 "reset possible")
        assert "person 1 in cam0-stop" not in _messages(cmd)  # never as holding now
        assert all(r.code in ("latched", "clearing") for r in cmd.reasons)
    assert [r.code for r in left.reasons] == ["latched", "clearing"]  # within clear_time
    assert [r.code for r in clear.reasons] == ["latched"]


def test_a_person_in_a_warning_zone_meanwhile_is_named_the_cell_is_not_clear():
    *_, clear = _latched_timeline(warn("cam0-warn", 0.5, person=2))
    assert clear.reset_possible
    assert clear.reasons[0].message == (
        "latched by person 1 in cam0-stop at 12:00:03; no STOP cause now (person 2 in "
        "cam0-warn), reset possible")
    assert "cell clear" not in clear.reasons[0].message


def test_the_latch_reason_names_old_latches_with_how_long_ago():
    state, _ = warmed(until=99.9)
    when = wall_clock(lambda: 700.0, lambda: LATCHED_AT + 600.0)
    state, _ = step(state, frame(100.0, prot("cam0-stop", person=1)), 100.0, MANUAL, when)
    _state, cmd = step(state, frame(700.0), 700.0, MANUAL, when)
    assert cmd.reasons[0].message.startswith(
        "latched by person 1 in cam0-stop at 12:00:03 (10 min ago); cell clear")


def _snapshots(*commands):
    """The adapters' snapshots of the policy's commands as the bus carries them."""
    now = time.monotonic()
    return [snapshot_of(Verdict(c.state, c.speed_scale, "", i + 1, c.to_dict()), now,
                        time.time(), i + 1, now, ("cam0",)) for i, c in enumerate(commands)]


def test_a_plc_reads_reason_latched_and_the_latch_zone_then_the_person_gone():
    inside, _still, _left, clear = _latched_timeline()
    snap_inside, snap_clear = _snapshots(inside, clear)
    out = ModbusOutput("127.0.0.1", free_port(),
                       state=mm.AdapterState(stale_s=3600.0, zones=ZONES), watchdog_s=0).start()
    plc = Plc(out.port)
    try:
        reason, zone, latched, possible = (mm.ADDRESS[n] for n in
                                           ("reason", "zone", "latched", "reset_possible"))
        out.publish(snap_inside)
        regs = plc.wait(lambda r: r[mm.ADDRESS["seq"]] == 1)
        assert regs, "the first snapshot never reached the registers"
        assert (regs[reason], regs[zone], regs[latched], regs[possible]) == (
            mm.REASON_CODES["protective_zone"], 2, 1, 0)
        out.publish(snap_clear)
        regs = plc.wait(lambda r: r[mm.ADDRESS["seq"]] == 2)
        assert regs, "the second snapshot never reached the registers"
        # reason 22: latched, no STOP cause holds; zone: where the latch began
        assert (regs[reason], regs[zone], regs[latched], regs[possible]) == (
            mm.REASON_CODES["latched"], 2, 1, 1)
    finally:
        plc.close()
        out.close()


@pytest.mark.slow  # the asyncua server's start and stop
def test_an_opc_ua_panel_reads_the_latch_as_history_beside_reset_possible():
    inside, _still, _left, clear = _latched_timeline()
    snap_inside, snap_clear = _snapshots(inside, clear)
    out = OpcUaOutput(OpcUaSettings(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/wm",
                                    stale_ms=3_600_000.0), camera_ids=("cam0",))
    out.start()
    try:
        with Client(out.settings.endpoint, timeout=10) as client:
            idx = client.get_namespace_index(NAMESPACE)

            def read(name: str):
                return client.get_node(f"ns={idx};s={node_id(name)}").read_value()

            out.publish(snap_inside)
            wait_for(lambda: read("Seq") == 1, what="the first snapshot on the server")
            assert read("Reason").startswith("person 1 in cam0-stop")
            assert read("ResetPossible") is False
            out.publish(snap_clear)
            wait_for(lambda: read("Seq") == 2, what="the second snapshot on the server")
            assert read("ResetPossible") is True and read("Latched") is True
            assert read("ReasonCode") == "latched" and read("ZoneId") == "cam0-stop"
            assert read("Reason") == ("latched by person 1 in cam0-stop at 12:00:03; cell "
                                      "clear, reset possible")
    finally:
        out.close()
