"""`monitor status` and `monitor reset` against a monitor on 127.0.0.1: they answer at the
monitor's first reply, not at the end of the query (a second queryable on the cell that never
finishes its answer must not hold them until --timeout)."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest

from monitor.bus.session import BusConfig, BusKeys, SafetyBus, open_session
from monitor.policy import Command, Reason
from tests.helpers import free_port

TIMEOUT_S = 30.0  # what the commands may wait; they must return long before it


@pytest.fixture
def monitor_and_a_hung_queryable():
    """A monitor (SafetyBus, peer listening on loopback) and a second session whose queryables
    on the status and reset keys take every query and never answer or finish it."""
    port = free_port()
    cfg = BusConfig(cell="lat", instance="mon-lat", listen=(f"tcp/127.0.0.1:{port}",),
                    allow_unsigned_resets=True)
    with SafetyBus(cfg, startup_check_s=0.2) as bus:
        bus.publish_command(Command("RUN", 1.0, ()))
        bus.update_status(fps=9.5)
        held: list = []
        hung_port = free_port()
        with open_session(BusConfig(cell="lat", instance="hung",
                                    listen=(f"tcp/127.0.0.1:{hung_port}",),
                                    connect=(f"tcp/127.0.0.1:{port}",))) as hung:
            keys = BusKeys.of("workcell/lat/")
            qs = [hung.declare_queryable(k, held.append) for k in (keys.status, keys.reset)]
            # the commands connect to both: the hung peer is there before the first query
            # (found by gossip only, it might be reached too late to hold anything)
            yield ["--connect", f"tcp/127.0.0.1:{port}", "--connect",
                   f"tcp/127.0.0.1:{hung_port}"], held, bus
            for q in qs:
                q.undeclare()
            held.clear()


def _run(connect: list[str], *argv: str) -> tuple[subprocess.CompletedProcess, float]:
    started = time.monotonic()
    out = subprocess.run([sys.executable, "-m", "monitor", *argv, "--cell", "lat", *connect,
                          "--timeout", f"{TIMEOUT_S:g}"],
                         capture_output=True, text=True, timeout=TIMEOUT_S + 30)
    return out, time.monotonic() - started


def test_status_returns_at_the_monitors_first_reply(monitor_and_a_hung_queryable):
    connect, held, _ = monitor_and_a_hung_queryable
    out, took = _run(connect, "status", "--json")
    assert out.returncode == 0, out.stderr
    status = json.loads(out.stdout)
    assert status["instance"] == "mon-lat" and status["fps"] == 9.5
    assert held, "the hung queryable never saw the query: the test proves nothing"
    # generous (process start, imports, a loaded machine); the old code waited TIMEOUT_S
    assert took < 10.0, f"monitor status took {took:.1f} s"


def test_status_prints_a_summary_by_default(monitor_and_a_hung_queryable):
    connect, _held, bus = monitor_and_a_hung_queryable
    bus.publish_command(Command("SLOW", 0.4, (Reason("warning_zone", "person 2 in W1",
                                                     zone_id="W1"),)))
    out, _took = _run(connect, "status")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("monitor mon-lat (cell lat), boot "), out.stdout
    assert lines[1:3] == ["command: SLOW x0.40", "  warning_zone [W1]: person 2 in W1"]
    assert "faults: none" in lines and "muted zones: none" in lines
    assert not out.stdout.lstrip().startswith("{")


def test_reset_reads_the_status_at_the_first_reply(monitor_and_a_hung_queryable):
    connect, held, _ = monitor_and_a_hung_queryable
    out, took = _run(connect, "reset", "--operator", "anna")
    # not latched: said by the CLI after reading the status (the old code spent its whole
    # --timeout on that status query and then reported no monitor at all)
    assert out.returncode == 1 and "not latched" in out.stdout, (out.stdout, out.stderr)
    assert held and took < 10.0, f"monitor reset took {took:.1f} s"


def test_reset_returns_at_the_monitors_answer(monitor_and_a_hung_queryable):
    from monitor.policy import Latch, ResetOutcome
    from monitor.wire.resets import LatchNonces

    connect, held, bus = monitor_and_a_hung_queryable
    latched = Command("STOP", 0.0, (), latched=True, latched_by=Latch(
        "protective_zone", "person 0 in P1", 1.0, nonce=LatchNonces(bus.boot)(1)))
    bus.publish_command(latched)
    started = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "monitor", "reset", "--operator", "anna",
                             "--cell", "lat", *connect,
                             "--timeout", f"{TIMEOUT_S:g}"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    got: list = []
    while not got and time.monotonic() - started < TIMEOUT_S:
        got = bus.poll_resets()  # the policy's part: decide and answer
        time.sleep(0.01)
    assert got, "no reset request reached the monitor"
    bus.publish_command(Command("RUN", 1.0, (), reset=ResetOutcome(
        "anna", True, "reset accepted", got[0].request_id)))
    stdout, stderr = proc.communicate(timeout=TIMEOUT_S + 30)
    took = time.monotonic() - started
    assert proc.returncode == 0 and "accepted" in stdout, (stdout, stderr)
    assert len(held) >= 2, "the hung queryables did not see both queries"
    assert took < 10.0, f"monitor reset took {took:.1f} s"


def _reset_against_a_rogue(tmp_path, *extra: str) -> tuple[str, str, int]:
    """A latched monitor with a signing key and a rogue session that answers every reset
    query at once with "accepted"; `monitor reset` run against both; the monitor's policy
    refuses (a person is still in the zone)."""
    from monitor.policy import Latch, ResetOutcome
    from monitor.wire.resets import LatchNonces
    from monitor.wire.signing import new_key_pair

    new_key_pair(tmp_path / "monitor.key")
    _, _, anna = new_key_pair(tmp_path / "anna.key")
    (tmp_path / "operators").write_text(f"anna {anna}\n")
    port = free_port()
    cfg = BusConfig(cell="rg", instance="mon-rg", listen=(f"tcp/127.0.0.1:{port}",),
                    signing_key=str(tmp_path / "monitor.key"),
                    operators_file=str(tmp_path / "operators"))
    with SafetyBus(cfg, startup_check_s=0.2) as bus, \
            open_session(BusConfig(cell="rg", instance="rogue",
                                   connect=(f"tcp/127.0.0.1:{port}",))) as rogue:
        bus.publish_command(Command("STOP", 0.0, (), latched=True, latched_by=Latch(
            "protective_zone", "person 0 in P1", 1.0, nonce=LatchNonces(bus.boot)(1))))
        keys = BusKeys.of("workcell/rg/")
        rogue.declare_queryable(keys.reset, lambda q: q.reply(keys.reset, json.dumps(
            {"schema": "workcell.safety.reset-answer/1", "accepted": True, "stage": "policy",
             "reason": "reset accepted", "state": "RUN", "instance": "mon-rg"})))
        proc = subprocess.Popen([sys.executable, "-m", "monitor", "reset", "--operator", "anna",
                                 "--key", str(tmp_path / "anna.key"), "--cell", "rg",
                                 "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "20",
                                 *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        got: list = []
        started = time.monotonic()
        while not got and time.monotonic() - started < TIMEOUT_S and proc.poll() is None:
            got = bus.poll_resets()
            time.sleep(0.01)
        if got:  # the policy's part: still a person in the zone
            bus.publish_command(Command("STOP", 0.0, (), reset=ResetOutcome(
                "anna", False, "refused: person 0 in zone P1", got[0].request_id)))
        stdout, stderr = proc.communicate(timeout=TIMEOUT_S + 30)
    return stdout, stderr, proc.returncode


def test_a_rogue_responders_accepted_is_not_believed_with_the_monitor_key(tmp_path):
    """Issue 31: a rogue queryable on the reset key answered "accepted" first and `monitor
    reset` exited 0 while the monitor stayed latched. With --monitor-key only the monitor's
    signed answer to this very request counts, and the output names who answered."""
    (tmp_path / "a").mkdir()
    stdout, stderr, code = _reset_against_a_rogue(tmp_path / "a")
    assert code == 0 and "NOT authenticated" in stdout + stderr, (stdout, stderr)  # the attack
    (tmp_path / "b").mkdir()
    stdout, stderr, code = _reset_against_a_rogue(
        tmp_path / "b", "--monitor-key", str(tmp_path / "b" / "monitor.key.pub"))
    assert code == 1 and "REFUSED" in stdout and "person 0" in stdout, (stdout, stderr)
    assert "answered by monitor mon-rg" in stdout and "signed by ed25519:" in stdout
    # and the rogue's answer is said, not silently dropped: someone else answers there
    assert "monitor reset: 1 answer ignored (1 unsigned): someone else answers on " \
        "workcell/rg/safety/reset" in stderr, stderr
