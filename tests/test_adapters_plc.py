"""`monitor bridge plc`: a real signed monitor on 127.0.0.1, the adapter as its own process
(`python -m monitor bridge plc`), a real pymodbus client reading the register map (docs/plc.md).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

pytest.importorskip("pymodbus")
import contextlib

from monitor.adapters import modbus_map as mm
from monitor.adapters.modbus import ModbusOutput
from monitor.adapters.snapshot import NOTE_CODES, snapshot_of
from monitor.bus.session import BusConfig, BusKeys, SafetyBus, open_session
from monitor.detector.test_model import TEST_MODEL_NOTE, TEST_MODEL_REASON
from monitor.policy import Command, Latch, Reason
from monitor.policy.model import ResetOutcome
from monitor.wire.consumer import COMMAND_SCHEMA, Verdict
from monitor.wire.signing import load_private_key, new_key_pair
from tests.helpers import free_port, wait_for
from tests.plc_kit import CELL, ROOT, TTL_MS, Plc, _env, start_adapter, stop_process

STATE, SCALE, REASON, ZONE, HEARTBEAT, STATUS = 0, 1, 4, 5, 7, 11
RUN, SLOW, STOP = 2, 1, 0

# a monitor in its own process (to kill or SIGSTOP it): signed RUN, repeated by the heartbeat
MONITOR = """
import sys, time
from monitor.bus.session import BusConfig, SafetyBus
from monitor.policy import Command
cfg = BusConfig(cell=sys.argv[1], instance="mon-plc", listen=(f"tcp/127.0.0.1:{sys.argv[2]}",),
                heartbeat_hz=20.0, ttl_ms=int(sys.argv[4]), signing_key=sys.argv[3])
with SafetyBus(cfg) as bus:
    print("up", flush=True)
    while True:  # the pipeline's steps: a command every 50 ms
        bus.publish_command(Command("RUN", 1.0))
        time.sleep(0.05)
"""










@pytest.fixture()
def keys(tmp_path):
    private, public, _ = new_key_pair(tmp_path / "monitor.key")
    return private, public


@pytest.fixture()
def cell(keys):
    """A signed monitor (SafetyBus in this process), the adapter process, a PLC client."""
    private, public = keys
    zport, mport = free_port(), free_port()
    cfg = BusConfig(cell=CELL, instance="mon-plc", listen=(f"tcp/127.0.0.1:{zport}",),
                    heartbeat_hz=20.0, ttl_ms=TTL_MS, signing_key=str(private),
                    stall_timeout=60.0)  # commands are handed in by the test, not a pipeline
    with SafetyBus(cfg) as bus:
        proc = start_adapter(zport, mport, public, "--watchdog-ms", "300")
        plc = Plc(mport)
        try:
            yield bus, plc, proc, zport
        finally:
            plc.close()
            stop_process(proc)


def test_the_plc_reads_stop_before_any_command_then_slow_run_stop_as_the_monitor_commands(
        cell):
    bus, plc, _proc, _ = cell
    first = plc.wait(lambda r: True)  # the bus's own startup STOP, or none yet
    assert first[STATE] == STOP and first[REASON] in (mm.REASON_CODES["no_command"],
                                                      mm.REASON_CODES["startup"])
    assert first[mm.ADDRESS["map_version"]] == mm.MAP_VERSION
    bus.publish_command(Command("SLOW", 0.4, (Reason("warning_zone", "person 1 in W",
                                                     zone_id="W"),)))
    slow = plc.wait(lambda r: r[STATE] == SLOW)
    assert slow and slow[SCALE] == 400 and slow[REASON] == 30 and slow[ZONE] == 2
    bus.publish_command(Command("RUN", 1.0))
    run = plc.wait(lambda r: r[STATE] == RUN)
    assert run and run[SCALE] == 1000 and run[REASON] == 0 and run[ZONE] == 0
    assert run[mm.ADDRESS["cameras_ok"]] == 1 and run[mm.ADDRESS["command_age_ms"]] < TTL_MS
    beats = {plc.read()[HEARTBEAT] for _ in range(5) if not time.sleep(0.03)}
    assert len(beats) >= 3  # the heartbeat moves with the adapter's ticks
    bus.publish_command(Command("STOP", 0.0, (Reason("protective_zone", "person 2 in P",
                                                     zone_id="P", person=2),)))
    stop = plc.wait(lambda r: r[STATE] == STOP)
    assert stop and stop[SCALE] == 0 and stop[REASON] == 10 and stop[ZONE] == 1


def test_an_adapter_started_before_any_monitor_reads_stop_no_command(keys):
    _, public = keys
    mport = free_port()
    proc = start_adapter(free_port(), mport, public)
    plc = Plc(mport)
    try:
        # at least 10 reads, and on until the heartbeat moved (a loaded host ticks late)
        seen: list = []
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and (len(seen) < 10
                                                or len({r[HEARTBEAT] for r in seen}) < 2):
            if (r := plc.read()) is not None:
                seen.append(r)
            time.sleep(0.02)
    finally:
        plc.close()
        stop_process(proc)
    assert len(seen) >= 10 and all(r[STATE] == STOP and r[SCALE] == 0 for r in seen)
    assert all(r[REASON] == mm.REASON_CODES["no_command"] and r[STATUS] & 0b10000
               for r in seen)
    assert len({r[HEARTBEAT] for r in seen}) > 1  # alive, and saying STOP


def _never_run_after(plc: Plc, t0: float, budget_s: float, watch_s: float) -> list:
    """(read start - t0, state) for every read in ``watch_s``; reads that STARTED later than
    ``budget_s`` after ``t0`` must all be STOP (a slow client never counts against us)."""
    seen = []
    while time.monotonic() - t0 < watch_s:
        started = time.monotonic() - t0
        r = plc.read()
        seen.append((started, None if r is None else r[STATE]))
    late = [s for t, s in seen if t > budget_s]
    assert late and all(s == STOP for s in late if s is not None), seen
    return seen


@pytest.mark.parametrize("how", ["kill", "sigstop"])
def test_a_killed_or_frozen_monitor_is_stop_on_the_plc_within_ttl(keys, how):
    private, public = keys
    zport, mport = free_port(), free_port()
    mon = subprocess.Popen([sys.executable, "-c", MONITOR, CELL, str(zport), str(private),
                            str(TTL_MS)], cwd=ROOT, env=_env(), stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    proc = plc = None
    try:
        assert mon.stdout.readline().strip() == "up"
        proc = start_adapter(zport, mport, public)
        plc = Plc(mport)
        assert plc.wait(lambda r: r[STATE] == RUN), "never RUN before the kill"
        t0 = time.monotonic()
        mon.send_signal(signal.SIGKILL if how == "kill" else signal.SIGSTOP)
        seen = _never_run_after(plc, t0, (TTL_MS + 100) / 1000.0, 1.5)
        stop_at = next(t for t, s in seen if s == STOP)
        print(f"{how}: STOP read {stop_at * 1000:.0f} ms after the signal")
        assert stop_at <= (TTL_MS + 100) / 1000.0 + 0.05, seen[:20]
    finally:
        if plc:
            plc.close()
        if proc:
            stop_process(proc)
        mon.send_signal(signal.SIGCONT)
        mon.kill()
        mon.wait(10)


def test_a_forged_run_on_the_bus_never_reaches_the_plc(cell, tmp_path):
    bus, plc, _, zport = cell
    bus.publish_command(Command("STOP", 0.0, (Reason("protective_zone", "person 1 in P",
                                                     zone_id="P"),)))
    assert plc.wait(lambda r: r[REASON] == 10)
    forger_key, _, _ = new_key_pair(tmp_path / "forger.key")
    forger = load_private_key(forger_key)
    k = BusKeys.of(f"workcell/{CELL}/")
    body = {"schema": COMMAND_SCHEMA, "cell": CELL, "instance": "mon-plc", "boot": "forged",
            "seq": 10**6, "state": "RUN", "speed_scale": 1.0, "ttl_ms": 1000,
            "wall": time.time(), "mono": 0.0}
    stop = threading.Event()
    with open_session(BusConfig(cell=CELL, instance="forger",
                                connect=(f"tcp/127.0.0.1:{zport}",))) as session:
        def forge() -> None:
            while not stop.is_set():
                body["wall"] = time.time()
                payload = json.dumps(body).encode()
                session.put(k.command, payload)  # unsigned
                session.put(k.command, payload, attachment=forger.sign(k.command, payload))
                body["seq"] += 1
                time.sleep(0.005)

        t = threading.Thread(target=forge)
        t.start()
        try:
            states = [r[STATE] for _ in range(60) if (r := plc.read()) is not None
                      and not time.sleep(0.01)]
        finally:
            stop.set()
            t.join()
    assert len(states) > 30 and set(states) == {STOP}


def _exception_code(resp) -> int | None:
    return getattr(resp, "exception_code", None) if resp.isError() else None


def test_bad_writes_garbage_and_a_flood_get_exception_codes_and_never_run(cell):
    bus, plc, proc, _ = cell
    bus.publish_command(Command("STOP", 0.0, (Reason("protective_zone", "person 1 in P",
                                                     zone_id="P"),)))
    assert plc.wait(lambda r: r[REASON] == 10)
    c = plc.client
    assert _exception_code(plc.write(STATE, RUN)) == mm.ILLEGAL_ADDRESS  # read-only
    assert _exception_code(plc.write(SCALE, 1000, 2)) == mm.ILLEGAL_ADDRESS
    assert _exception_code(plc.write(31, 0, 5)) == mm.ILLEGAL_ADDRESS  # spans read-only
    assert _exception_code(plc.write(mm.ADDRESS["reset_request"], 1)) == mm.ILLEGAL_ADDRESS
    assert _exception_code(c.write_coil(0, True, device_id=1)) == mm.ILLEGAL_FUNCTION
    assert _exception_code(c.read_holding_registers(mm.SIZE, count=2, device_id=1)) == \
        mm.ILLEGAL_ADDRESS
    # garbage on the wire: a raw socket sends bytes that are no Modbus frame
    mport = c.comm_params.port
    for junk in (b"\x00" * 7, os.urandom(300), b"GET / HTTP/1.1\r\n\r\n",
                 b"\x00\x01\x00\x00\x00\x06\x01\x2b\x0e\x01\x00\x00"):
        with socket.create_connection(("127.0.0.1", mport), timeout=2) as s:
            s.sendall(junk)
            s.settimeout(0.2)
            with contextlib.suppress(TimeoutError, ConnectionError):
                s.recv(256)
    # a flood from four clients at once
    def flood() -> None:
        p = Plc(mport)
        for i in range(300):
            p.write(STATE, RUN) if i % 2 else p.read()
        p.close()

    threads = [threading.Thread(target=flood) for _ in range(4)]
    for t in threads:
        t.start()
    states = []
    while any(t.is_alive() for t in threads):
        r = plc.read()
        if r is not None:
            states.append(r[STATE])
    for t in threads:
        t.join()
    after = plc.wait(lambda r: True)
    assert proc.poll() is None, "the adapter died"
    assert states and set(states) == {STOP} and after[STATE] == STOP
    assert after[mm.ADDRESS["write_errors"]] >= 600


def test_notes_every_command_carries_never_hide_a_clean_run(cell):
    """The test model's notice (and a muted zone) ride in every command after its causes: a
    RUN with them reads reason 0 and zone 0 (it read 999, "any other code"); a STOP still
    reads its cause."""
    bus, plc, _, _ = cell
    assert TEST_MODEL_REASON in NOTE_CODES
    note = Reason(TEST_MODEL_REASON, TEST_MODEL_NOTE)
    muted = Reason("muted", "zone W muted by anna until 10:00", zone_id="W")
    bus.publish_command(Command("RUN", 1.0, (note,)))
    run = plc.wait(lambda r: r[STATE] == RUN, 20.0)
    assert run and run[REASON] == 0 and run[ZONE] == 0, run
    bus.publish_command(Command("RUN", 1.0, (muted, note)))
    run_muted = plc.wait(lambda r: r[STATE] == RUN and r[mm.ADDRESS["seq"]] != run[6], 20.0)
    assert run_muted and run_muted[REASON] == 0 and run_muted[ZONE] == 0, run_muted
    bus.publish_command(Command("STOP", 0.0, (Reason("protective_zone", "person 1 in P",
                                                     zone_id="P"), muted, note)))
    stop = plc.wait(lambda r: r[STATE] == STOP, 20.0)
    assert stop and stop[REASON] == mm.REASON_CODES["protective_zone"] and stop[ZONE] == 1


def test_the_plc_watchdog_stopping_raises_an_alert_on_the_bus(cell):
    _bus, plc, _, zport = cell
    alerts: list[dict] = []
    k = BusKeys.of(f"workcell/{CELL}/")
    with open_session(BusConfig(cell=CELL, instance="listener",
                                connect=(f"tcp/127.0.0.1:{zport}",))) as session:
        sub = session.declare_subscriber(k.alert, lambda s: alerts.append(
            json.loads(s.payload.to_bytes())))
        for i in range(1, 30):  # the PLC writes a changing value every 20 ms
            last = time.monotonic()
            assert not plc.write(mm.ADDRESS["plc_watchdog"], i).isError()
            time.sleep(0.02)
        assert not plc.read()[STATUS] & 0b10
        n_before = len([a for a in alerts if "not changed" in a.get("message", "")])
        got = wait_for(lambda: [a for a in alerts if a.get("kind") == "plc_watchdog"
                                and "not changed" in a.get("message", "")])
        sub.undeclare()
    assert n_before == 0 and got and got[0]["source"] == "plc"
    assert time.monotonic() - last >= 0.3  # not before the PLC's watchdog time
    assert plc.read()[STATUS] & 0b10  # the PLC can see it too


def test_a_frozen_adapter_loop_reads_stop_and_a_still_heartbeat():
    port = free_port()
    out = ModbusOutput("127.0.0.1", port, state=mm.AdapterState(stale_s=0.2),
                       watchdog_s=0).start()
    plc = Plc(port)
    try:
        cmd = {"state": "RUN", "speed_scale": 1.0, "reasons": []}
        now = time.monotonic()
        out.publish(snapshot_of(Verdict("RUN", 1.0, "", 5, cmd), now, time.time(), 7, now))
        fresh = plc.read()
        assert fresh[STATE] == RUN and fresh[HEARTBEAT] == 7
        # nothing publishes any more (the loop is frozen): the map itself falls to STOP
        late = plc.wait(lambda r: r[STATE] == STOP)
        assert late and late[HEARTBEAT] == 7 and late[STATUS] & 1
        assert late[REASON] == mm.REASON_CODES["adapter_stale"]
        assert late[mm.ADDRESS["snapshot_age_ms"]] >= 200
        assert late[mm.ADDRESS["command_age_ms"]] >= 200  # the age grows while frozen
    finally:
        plc.close()
        out.close()


def test_inputs_only_from_the_allow_list_and_only_in_range():
    port = free_port()
    resets: list[str] = []
    out = ModbusOutput("127.0.0.1", port, state=mm.AdapterState(inputs_enabled=True),
                       watchdog_s=0, allow=frozenset({"127.0.0.2"}),
                       on_reset=lambda peer: resets.append(peer) or "accepted").start()
    plc = Plc(port)
    try:
        reset = mm.ADDRESS["reset_request"]
        assert _exception_code(plc.write(reset, 1)) == mm.ILLEGAL_FUNCTION  # not listed
        assert _exception_code(plc.write(mm.ADDRESS["plc_watchdog"], 1)) == \
            mm.ILLEGAL_FUNCTION
        out.allow = frozenset({"127.0.0.1"})
        assert _exception_code(plc.write(reset, 5)) == mm.ILLEGAL_VALUE
        assert _exception_code(plc.write(mm.ADDRESS["monitoring_case"], 300)) == \
            mm.ILLEGAL_VALUE
        assert not plc.write(mm.ADDRESS["monitoring_case"], 3).isError()
        assert not plc.write(reset, 1).isError()
        assert not plc.write(reset, 1).isError()  # no rising edge: not a second reset
        r = plc.wait(lambda r: r[mm.ADDRESS["reset_result"]] == 2)
        assert r and resets == ["127.0.0.1"] and r[mm.ADDRESS["reset_count"]] == 1
        assert r[mm.ADDRESS["case_echo"]] == 3
        assert r[STATE] == STOP  # no snapshot yet
    finally:
        plc.close()
        out.close()


def _monitor_with_operator_anna(tmp_path, private):
    """Operator anna's key pair and file, and a monitor's bus config that trusts her:
    (anna's private key, the config, the bus port, a Modbus port)."""
    op_key, _, op_text = new_key_pair(tmp_path / "anna.key")
    operators = tmp_path / "operators"
    operators.write_text(f"anna {op_text}\n")
    os.chmod(operators, 0o644)
    zport, mport = free_port(), free_port()
    cfg = BusConfig(cell=CELL, instance="mon-plc", listen=(f"tcp/127.0.0.1:{zport}",),
                    heartbeat_hz=20.0, ttl_ms=TTL_MS, signing_key=str(private),
                    operators_file=str(operators), stall_timeout=60.0)
    return op_key, cfg, zport, mport


def _latched(bus) -> Latch:
    """The monitor publishes a STOP latched by person 1 in P, waiting for a reset."""
    latch = Latch("protective_zone", "person 1 in P", 0.0, "P", 1, nonce="1-abcdef")
    bus.publish_command(Command("STOP", 0.0, (Reason("latched", "waiting for a reset"),),
                                latched=True, latched_by=latch, reset_possible=True))
    return latch


def test_a_plc_reset_reaches_the_monitor_as_the_operators_signed_reset(keys, tmp_path):
    private, public = keys
    op_key, cfg, zport, mport = _monitor_with_operator_anna(tmp_path, private)
    with SafetyBus(cfg) as bus:
        _latched(bus)
        proc = start_adapter(zport, mport, public, "--inputs", "--allow-client", "127.0.0.1",
                             "--reset-operator", "anna", "--reset-key", str(op_key))
        plc = Plc(mport)
        try:
            assert plc.wait(lambda r: r[mm.ADDRESS["latched"]] == 1), plc.read()
            assert not plc.write(mm.ADDRESS["reset_request"], 1).isError()
            got = wait_for(bus.poll_resets)
            assert got and got[0].operator == "anna" and got[0].latch == "1-abcdef"
            assert "PLC" in got[0].note and "127.0.0.1" in got[0].note
            bus.publish_command(Command(
                "RUN", 1.0, reset=ResetOutcome("anna", True, "reset", got[0].request_id)))
            r = plc.wait(lambda r: r[mm.ADDRESS["reset_result"]] == 2)
            assert r and r[mm.ADDRESS["reset_count"]] == 1
        finally:
            plc.close()
            err = stop_process(proc)
    assert "reset request from client 127.0.0.1" in err


def test_a_rogue_responders_accepted_never_reads_reset_accepted_on_the_plc(keys, tmp_path):
    """A rogue queryable on the reset key answers the PLC's reset "accepted" at once; the
    monitor refuses it. The adapter believes only the answer its --monitor-key signed for that
    request: reset_result reads 3 (refused), never 2 (before: 2, the rogue's)."""
    private, public = keys
    op_key, cfg, zport, mport = _monitor_with_operator_anna(tmp_path, private)
    keys_of = BusKeys.of(f"workcell/{CELL}/")
    with SafetyBus(cfg) as bus, open_session(BusConfig(
            cell=CELL, instance="rogue", connect=(f"tcp/127.0.0.1:{zport}",))) as rogue:
        rogue.declare_queryable(keys_of.reset, lambda q: q.reply(keys_of.reset, json.dumps(
            {"schema": "workcell.safety.reset-answer/1", "accepted": True, "stage": "policy",
             "reason": "reset accepted", "state": "RUN", "instance": "mon-plc"})))
        latch = _latched(bus)
        proc = start_adapter(zport, mport, public, "--inputs", "--allow-client", "127.0.0.1",
                             "--reset-operator", "anna", "--reset-key", str(op_key))
        plc = Plc(mport)
        try:
            assert plc.wait(lambda r: r[mm.ADDRESS["latched"]] == 1), plc.read()
            assert not plc.write(mm.ADDRESS["reset_request"], 1).isError()
            got = wait_for(bus.poll_resets)
            assert got and got[0].operator == "anna"
            bus.publish_command(Command(
                "STOP", 0.0, latched=True, latched_by=latch,
                reset=ResetOutcome("anna", False, "refused: person 1 in P", got[0].request_id)))
            r = plc.wait(lambda r: r[mm.ADDRESS["reset_result"]] in (2, 3))
            assert r and r[mm.ADDRESS["reset_result"]] == 3, r
        finally:
            plc.close()
            stop_process(proc)


@pytest.mark.parametrize("extra,needle", [
    (["--modbus-listen", "0.0.0.0:5020"], "--allow-network"),
    (["--inputs"], "--allow-client"),
    (["--inputs", "--allow-client", "127.0.0.1"], "--reset-operator"),
    (["--allow-client", "plc.local"], "not an IP address"),
])
def test_unsafe_or_bad_options_are_a_one_line_error(keys, extra, needle):
    _, public = keys
    proc = subprocess.run([sys.executable, "-m", "monitor", "bridge", "plc", "--connect",
                           f"tcp/127.0.0.1:{free_port()}", "--monitor-key", str(public),
                           *extra], cwd=ROOT, env=_env(), capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode != 0 and needle in proc.stderr
    assert "Traceback" not in proc.stderr


def test_the_register_map_in_the_docs_is_the_one_in_code():
    doc = (ROOT / "docs" / "plc.md").read_text()
    for table in (mm.markdown_table(), mm.reasons_table(), mm.bits_table()):
        assert table in doc
