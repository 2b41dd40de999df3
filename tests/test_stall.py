"""A frozen monitor (SIGSTOP: a paused VM, a long GC) must not resume with RUN: after SIGCONT it
stays in STOP, latched, with a critical ``monitor_stalled`` alert and a log line. A real
`monitor run` subprocess and a real Zenoh peer in this test on 127.0.0.1 (scouting off)."""

from __future__ import annotations

import json
import signal
import time

import pytest

from monitor.bus.session import BusConfig, BusKeys, open_session
from tests.processes import Monitor, wait_for, write_config

FREEZE_S = 6.0  # well past frame_timeout (the stall threshold), under the link leases
CLEAR_TIME = 1.0  # policy.clear_time default: RUN could return this long after a cause


@pytest.mark.slow
def test_sigstop_then_sigcont_stays_stopped_latched_with_a_stall_alert(tmp_path,
                                                                        synthetic_model):
    # frame_timeout 3 s (the stall threshold): at a load of 5-10 on 2 cores the monitor's
    # start-up left a 2.7 s gap between frames, which a 1 s threshold latched as a stall before
    # the first RUN this test needs; max_frame_age 3 s (under the freeze): at a load of 8 a
    # frame was 1.15 s old when its step ended and latched frame_late
    # the link leases (the monitor's appended to [bus], ours below) outlast the freeze: this
    # test is about the monitor's stall handling, not about Zenoh re-connecting after a peer
    # went silent past its lease (consumers then see silence and STOP: tests/test_rogue.py)
    config, port = write_config(tmp_path, synthetic_model,
                                "lease_ms = 10000\n"
                                "[policy]\nframe_timeout = 3.0\nmax_frame_age = 3.0\n")
    mon = Monitor(config, port, tmp_path / "monitor.log")
    session = None
    try:
        wait_for(mon.listening, 120, "the bus port", mon)
        session = open_session(BusConfig(cell="t6", instance="stall-test", lease_ms=10000,
                                         connect=(f"tcp/127.0.0.1:{port}",)))
        keys = BusKeys.of("workcell/t6/")
        commands: list[dict] = []
        alerts: list[dict] = []
        session.declare_subscriber(keys.command, lambda s: commands.append(
            json.loads(s.payload.to_bytes())))
        session.declare_subscriber(keys.alert, lambda s: alerts.append(
            json.loads(s.payload.to_bytes())))
        # the empty cell: start-up STOP, then RUN after clear_time
        wait_for(lambda: any(c["state"] == "RUN" for c in commands), 120, "RUN", mon)

        mon.proc.send_signal(signal.SIGSTOP)
        frozen_at = time.monotonic()
        time.sleep(FREEZE_S)  # the freeze itself is what is tested
        n_before = len(commands)
        mon.proc.send_signal(signal.SIGCONT)
        resumed_at = time.monotonic()

        alert = wait_for(lambda: next((a for a in list(alerts)
                                         if a["kind"] == "monitor_stalled"), None),
                           10, "the monitor_stalled alert", mon)
        assert alert["severity"] == "critical" and "stalled for" in alert["message"]
        # long enough after the resume that an unlatched STOP would have become RUN again
        wait_for(lambda: any(c["mono"] > resumed_at + CLEAR_TIME + 1.0 for c in commands),
                   10, "commands well after the resume", mon)
        after = commands[n_before:]
        assert after, "no command after SIGCONT"
        assert all(c["mono"] >= frozen_at for c in after)  # same monotonic clock (one host)
        assert [c["state"] for c in after if c["state"] != "STOP"] == [], \
            [(round(c["mono"] - resumed_at, 3), c["state"]) for c in after]
        stalled = [c for c in after
                   if any(r.get("fault") == "monitor_stalled" for r in c["reasons"])]
        assert stalled and stalled[0]["latched"]
        # the pipeline's own view (the bus heartbeat may add a "stalled" STOP of its own when a
        # step is slow on this loaded machine; that one carries no latch flag)
        decided = [c for c in after if {r["code"] for r in c["reasons"]} != {"stalled"}]
        assert decided and all(c["latched"] for c in decided), \
            [(c["reasons"], c["latched"]) for c in decided if not c["latched"]]
        log = [json.loads(line) for line in mon.log_path.read_text().splitlines()
               if line.startswith("{")]
        lines = [e for e in log if e["event"] == "monitor stalled: STOP latched"]
        assert lines and lines[0]["level"] == "error" and lines[0]["gap_s"] >= FREEZE_S - 0.1
    finally:
        if session is not None:
            session.close()
        mon.close()
