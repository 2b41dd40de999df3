"""A cell with two monitors (roles monitor-a, monitor-b) seen by the PLC through `monitor
bridge plc --expect`: monitor-b latched for a person, monitor-a reset and going RUN; a real
pymodbus client sampling the registers as fast as it can must never read RUN in between (the
cell verdict is made from every role before anything is written, docs/consumer.md)."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

pytest.importorskip("pymodbus")

from monitor.bus.session import BusConfig, SafetyBus
from monitor.policy import Command, Latch, Reason
from monitor.wire.signing import new_key_pair
from tests.helpers import free_port, wait_for
from tests.plc_kit import CELL, ROOT, TTL_MS, Plc, _env, stop_process

STATE, RUN, STOP = 0, 2, 0


def _bus(role: str, key, port: int) -> SafetyBus:
    return SafetyBus(BusConfig(cell=CELL, role=role, instance=f"{role}-host",
                               listen=(f"tcp/127.0.0.1:{port}",), heartbeat_hz=20.0,
                               ttl_ms=TTL_MS, signing_key=str(key), stall_timeout=60.0))


@pytest.mark.slow
def test_one_monitor_going_run_never_shows_run_while_the_other_is_latched(tmp_path):
    keys = {r: new_key_pair(tmp_path / f"{r}.key")[:2] for r in ("monitor-a", "monitor-b")}
    za, zb, mport = free_port(), free_port(), free_port()
    why = "person 1 in P"
    latched = Command("STOP", 0.0, (Reason("protective_zone", why, zone_id="P", person=1),),
                      latched_by=Latch("protective_zone", why, 0.0, "P"))
    with _bus("monitor-a", keys["monitor-a"][0], za) as a, \
            _bus("monitor-b", keys["monitor-b"][0], zb) as b:
        b.publish_command(latched)
        a.publish_command(latched)
        proc = subprocess.Popen(
            [sys.executable, "-m", "monitor", "bridge", "plc", "--connect",
             f"tcp/127.0.0.1:{za}", "--connect", f"tcp/127.0.0.1:{zb}", "--cell", CELL,
             "--expect", f"monitor-a={keys['monitor-a'][1]}",
             "--expect", f"monitor-b={keys['monitor-b'][1]}", "--ttl-ms", str(TTL_MS),
             "--modbus-listen", f"127.0.0.1:{mport}", "--zone", "P"],
            cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        plc = None
        try:
            plc = Plc(mport) if wait_for(lambda: _listening(proc, mport), 30.0) else None
            assert plc is not None, "the adapter's Modbus server did not come up"
            seen: list[int | None] = []
            # monitor-a: reset accepted, RUN and repeated; monitor-b stays latched
            a.publish_command(Command("RUN", 1.0))
            t0 = time.monotonic()
            while time.monotonic() - t0 < 1.5:
                if (i := int((time.monotonic() - t0) / 0.05)) % 4 == 0 and i:
                    a.publish_command(Command("STOP", 0.0, (Reason("clearing", "x"),)))
                    a.publish_command(Command("RUN", 1.0))
                r = plc.read()
                seen.append(None if r is None else r[STATE])
            assert len([s for s in seen if s is not None]) >= 10  # sampled, not idle
            assert all(s == STOP for s in seen if s is not None), seen
            # the test can see RUN: monitor-b released too
            b.publish_command(Command("RUN", 1.0))
            assert plc.wait(lambda r: r[STATE] == RUN), "never RUN with both RUN"
        finally:
            if plc is not None:
                plc.close()
            stop_process(proc)


def _listening(proc: subprocess.Popen, port: int) -> bool:
    import socket

    if proc.poll() is not None:
        raise AssertionError(f"the adapter exited: {proc.communicate()[1]}")
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0
