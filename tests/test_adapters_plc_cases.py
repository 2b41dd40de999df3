"""The PLC selects zone sets through `monitor bridge plc` (register 34, docs/plc.md and
docs/cases.md): a real signed monitor side (SafetyBus and the selections' receiver, the switch
of monitor/cases/sets.py deciding), the adapter as its own process, real pymodbus clients."""

from __future__ import annotations

import json
import threading
import time

import pytest

pytest.importorskip("pymodbus")

from pymodbus.client import ModbusTcpClient

from monitor.adapters import modbus_map as mm
from monitor.bus.session import BusConfig, BusKeys, SafetyBus, open_session
from monitor.cases.receiver import CaseReceiver
from monitor.cases.sets import (
    CasePlan,
    Selection,
    ZoneSet,
    apply_events,
    in_force,
    initial_case,
)
from monitor.policy import Command, Reason
from monitor.wire.signing import new_key_pair
from tests.helpers import free_port, wait_for
from tests.plc_kit import CELL, TTL_MS, Plc, start_adapter, stop_process

CASE = mm.ADDRESS["monitoring_case"]
ECHO, RESULT, COUNT, SETS = (mm.ADDRESS[n] for n in ("case_echo", "case_result", "case_count",
                                                     "case_sets"))
PLAN = CasePlan((ZoneSet("A", frozenset({"station-a"})), ZoneSet("B", frozenset({"station-b"}))),
                default="A", switch_over_s=0.6)


def _code(resp) -> int | None:
    return getattr(resp, "exception_code", None) if resp.isError() else None


class MonitorSide:
    """What the monitor does with selections, every 50 ms: take the receiver's events, switch
    (the union while switching over) and publish a signed command carrying ``zone_sets``. The
    person stands at station B: STOP whenever B applies."""

    def __init__(self, bus: SafetyBus, receiver: CaseReceiver | None) -> None:
        self.bus, self.receiver = bus, receiver
        self.events: list = []
        self.sets: list[tuple[str, ...]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> MonitorSide:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def _run(self) -> None:
        state = initial_case(PLAN, time.monotonic())
        while not self._stop.wait(0.05):
            now = time.monotonic()
            events = self.receiver.poll() if self.receiver else ()
            self.events.extend(events)
            state = apply_events(PLAN, state, events, now)
            zones = in_force(PLAN, state, now)
            self.sets.append(zones.sets)
            at_b = "B" in zones.sets or zones.faults
            self.bus.publish_command(
                Command("STOP", 0.0, (Reason("protective_zone", "person 1 in station-b",
                                             zone_id="station-b"),), zone_sets=zones.sets)
                if at_b else Command("RUN", 1.0, zone_sets=zones.sets))


@pytest.fixture()
def side(tmp_path):
    """A signed monitor with a selectors file naming the adapter's selector "plc"."""
    private, public, _ = new_key_pair(tmp_path / "monitor.key")
    sel_key, _, sel_text = new_key_pair(tmp_path / "plc-selector.key")
    selectors = tmp_path / "selectors"
    selectors.write_text(f"plc {sel_text}\n")
    zport = free_port()
    cfg = BusConfig(cell=CELL, instance="mon-plc", listen=(f"tcp/127.0.0.1:{zport}",),
                    heartbeat_hz=20.0, ttl_ms=TTL_MS, signing_key=str(private),
                    selectors_file=str(selectors), stall_timeout=60.0)
    return cfg, public, sel_key, zport


def _case_args(sel_key, sets: str = "A,B,X") -> tuple[str, ...]:
    return ("--inputs", "--allow-client", "127.0.0.1", "--case-key", str(sel_key),
            "--case-selector", "plc", "--case-sets", sets, "--case-timeout", "1")


def _alerts(zport: int, into: list):
    session = open_session(BusConfig(cell=CELL, instance="listener",
                                     connect=(f"tcp/127.0.0.1:{zport}",)))
    session.declare_subscriber(BusKeys.of(f"workcell/{CELL}/").alert,
                               lambda s: into.append(json.loads(s.payload.to_bytes())))
    return session


def test_the_plc_writing_2_selects_set_b_signed_and_reads_the_switch_over(side):
    cfg, public, sel_key, zport = side
    mport = free_port()
    alerts: list[dict] = []
    with SafetyBus(cfg) as bus, CaseReceiver.for_bus(bus.session, bus.config, PLAN,
                                                      bus.signed_answer) as rx, \
            MonitorSide(bus, rx) as mon, _alerts(zport, alerts):
        started_ms = int(time.time() * 1000)
        proc = start_adapter(zport, mport, public, *_case_args(sel_key))
        plc = Plc(mport)
        try:
            r = plc.wait(lambda r: r[0] == 2 and r[SETS] == 0b01)  # A: RUN
            assert r and r[ECHO] == 0 and r[RESULT] == 0 and r[COUNT] == 0
            assert not plc.write(CASE, 2).isError()
            during = plc.wait(lambda r: r[SETS] == 0b11)  # the union A+B: STOP
            assert during and during[0] == 0
            after = plc.wait(lambda r: r[SETS] == 0b10)  # B alone after switch_over_s
            assert after and after[0] == 0 and after[RESULT] == 2 and after[ECHO] == 2
            assert after[COUNT] == 1 and after[CASE] == 2
            got = [e for e in mon.events if isinstance(e, Selection)]
            assert len(got) == 1 and got[0].set_id == "B" and got[0].selector == "plc"
            assert got[0].seq >= started_ms  # a restarted adapter's seq is above the last
            assert ("A", "B") in mon.sets and mon.sets[-1] == ("B",)

            # writing the same value again is no change: nothing sent
            assert not plc.write(CASE, 2).isError()
            # an index outside the table: exception 03, nothing sent, nothing stored
            assert _code(plc.write(CASE, 4)) == mm.ILLEGAL_VALUE
            assert _code(plc.write(CASE, 255)) == mm.ILLEGAL_VALUE
            # 0: no selection, nothing sent; the monitor keeps B
            assert not plc.write(CASE, 0).isError()
            # a client not on the allow-list (source 127.0.0.2): exception 01, nothing sent
            other = ModbusTcpClient("127.0.0.1", port=mport, timeout=2, retries=0,
                                    source_address=("127.0.0.2", 0))
            assert other.connect()
            try:
                assert _code(other.write_register(CASE, 1, device_id=1)) == \
                    mm.ILLEGAL_FUNCTION
            finally:
                other.close()
            time.sleep(0.5)
            r = plc.read()
            assert r[CASE] == 0 and r[COUNT] == 1 and r[SETS] == 0b10
            assert len(mon.events) == 1, mon.events

            # a set the monitor does not know: refused, an alert, the echo keeps B
            assert not plc.write(CASE, 3).isError()
            refused = plc.wait(lambda r: r[RESULT] == 3)
            assert refused and refused[ECHO] == 2 and refused[COUNT] == 2
            got = wait_for(lambda: [a for a in alerts if a.get("kind") == "plc_case"])
            assert got and "refused" in got[0]["message"] and "'X'" in got[0]["message"]
            assert got[0]["source"] == "plc"
            seqs = wait_for(lambda: len(s := [e.seq for e in mon.events
                                              if isinstance(e, Selection)]) == 2 and s)
            assert seqs and seqs[1] > seqs[0]  # the second selection's seq grew
            assert all(s in {"A", "B"} for sets in mon.sets for s in sets)
        finally:
            plc.close()
            err = stop_process(proc)
    assert "selects zone set 2 (B)" in err and "accepted" in err
    assert "nothing sent" in err


def test_an_unanswered_selection_reads_no_answer_and_raises_an_alert(side):
    cfg, public, sel_key, zport = side
    mport = free_port()
    alerts: list[dict] = []
    with SafetyBus(cfg) as bus, _alerts(zport, alerts):  # no receiver: nobody answers
        bus.publish_command(Command("RUN", 1.0))
        proc = start_adapter(zport, mport, public, *_case_args(sel_key))
        plc = Plc(mport)
        try:
            assert not plc.write(CASE, 1).isError()
            pending = plc.read()
            assert pending[RESULT] in (1, 4) and pending[COUNT] == 1
            r = plc.wait(lambda r: r[RESULT] == 4)
            assert r and r[ECHO] == 0
            got = wait_for(lambda: [a for a in alerts if a.get("kind") == "plc_case"])
            assert got and "no_answer" in got[0]["message"]
        finally:
            plc.close()
            stop_process(proc)


def test_without_a_case_key_register_34_is_stored_only(side, tmp_path):
    cfg, public, _sel_key, zport = side
    op_key, _, _ = new_key_pair(tmp_path / "anna.key")
    mport = free_port()
    with SafetyBus(cfg) as bus, CaseReceiver.for_bus(bus.session, bus.config, PLAN,
                                                      bus.signed_answer) as rx:
        bus.publish_command(Command("RUN", 1.0))
        proc = start_adapter(zport, mport, public, "--inputs", "--allow-client", "127.0.0.1",
                             "--reset-operator", "anna", "--reset-key", str(op_key))
        plc = Plc(mport)
        try:
            assert not plc.write(CASE, 2).isError()
            assert not plc.write(CASE, 200).isError()  # 0..255 as before: no table
            r = plc.wait(lambda r: r[ECHO] == 200)
            time.sleep(0.5)
            assert r and r[RESULT] == 0 and r[COUNT] == 0
            assert rx.poll() == ()
        finally:
            plc.close()
            err = stop_process(proc)
    assert "stored only" in err


@pytest.mark.parametrize("extra,needle", [
    (["--case-key", "k", "--case-selector", "plc", "--case-sets", "A,B"], "needs --inputs"),
    (["--inputs", "--allow-client", "127.0.0.1", "--case-key", "k"], "go together"),
    (["--inputs", "--allow-client", "127.0.0.1", "--case-key", "k", "--case-selector", "plc",
      "--case-sets", "A,,B"], "distinct, non-empty"),
    (["--inputs", "--allow-client", "127.0.0.1", "--case-key", "k", "--case-selector", "plc",
      "--case-sets", "A,B,A"], "distinct, non-empty"),
    (["--inputs", "--allow-client", "127.0.0.1", "--case-key", "/nonexistent/k",
      "--case-selector", "plc", "--case-sets", "A,B"], "/nonexistent/k"),
])
def test_bad_case_options_are_a_one_line_error(side, extra, needle):
    import subprocess
    import sys

    from tests.plc_kit import ROOT, _env

    _cfg, public, _, _ = side
    proc = subprocess.run([sys.executable, "-m", "monitor", "bridge", "plc", "--connect",
                           f"tcp/127.0.0.1:{free_port()}", "--monitor-key", str(public),
                           "--modbus-listen", f"127.0.0.1:{free_port()}", *extra],
                          cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and needle in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
