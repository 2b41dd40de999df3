"""Two processes over tcp/127.0.0.1: a service-side publisher and `monitor watch`."""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from monitor.bus.session import BusConfig, BusKeys, open_session
from tests.helpers import free_port

TTL_MS = 300
HZ = 10.0


def publisher_main(port: int, cell: str) -> None:
    """The service side: a pipeline loop handing a command to SafetyBus every 50 ms."""
    from monitor.bus.session import BusConfig, SafetyBus
    from monitor.policy import Command, Reason

    script = [("RUN", 1.0), ("SLOW", 0.5), ("STOP", 0.0), ("RUN", 1.0)]
    cfg = BusConfig(cell=cell, instance="mon-test", listen=(f"tcp/127.0.0.1:{port}",),
                    heartbeat_hz=HZ, ttl_ms=TTL_MS, config_hash="h1")
    with SafetyBus(cfg) as bus:
        deadline = time.monotonic() + 20
        while not bus._pub_command.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)  # wait for the watcher so it sees the whole script
        time.sleep(0.3)
        start = time.monotonic()
        while True:  # runs until the test kills this process
            i = min(int((time.monotonic() - start) / 0.3), len(script) - 1)
            state, scale = script[i]
            reasons = () if state == "RUN" else (Reason("test", f"step {i}"),)
            bus.publish_command(Command(state, scale, reasons, since=start + 0.3 * i))
            time.sleep(0.05)


class Watcher:
    """`monitor watch --json -v` as a subprocess; its stdout lines parsed in a thread."""

    def __init__(self, port: int, cell: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "monitor", "watch", "--cell", cell, "--json", "-v",
             "--connect", f"tcp/127.0.0.1:{port}"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.events: list[dict] = []
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.events.append(json.loads(line))

    def wait(self, pred, timeout: float = 30.0, start: int = 0) -> dict | None:
        """First event from index ``start`` on that matches ``pred``."""
        deadline = time.monotonic() + timeout
        seen = start
        while time.monotonic() < deadline:
            while seen < len(self.events):
                ev = self.events[seen]
                seen += 1
                if pred(ev):
                    return ev
            time.sleep(0.005)
        return None

    def stop(self) -> str:
        self.proc.send_signal(signal.SIGINT)
        try:
            _, err = self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        return err



@pytest.mark.slow
def test_publisher_and_watcher_in_two_processes():
    port, cell = free_port(), "wt"
    ctx = multiprocessing.get_context("spawn")  # fork after zenoh.open breaks sessions
    pub = ctx.Process(target=publisher_main, args=(port, cell), daemon=True)
    pub.start()
    watcher = Watcher(port, cell)
    try:
        # 1. the script arrives in order, with increasing seq, and the watcher follows it
        final_run = watcher.wait(lambda e: e["event"] == "verdict" and e["state"] == "RUN"
                                 and e["seq"] and e["seq"] > 3, timeout=20)
        assert final_run is not None, watcher.events[-5:]
        t_steady = time.monotonic()
        time.sleep(2.2)  # heartbeats only
        commands = [e for e in watcher.events if e["event"] == "command"]
        assert all(e["rejected"] is None for e in commands)
        seqs = [e["body"]["seq"] for e in commands]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
        changes = [e["body"]["state"] for e in commands if not e["body"]["heartbeat"]]
        assert changes[:4] == ["RUN", "SLOW", "STOP", "RUN"]
        verdict_states = [e["state"] for e in watcher.events if e["event"] == "verdict"]
        assert verdict_states[verdict_states.index("RUN"):][:4] == ["RUN", "SLOW", "STOP", "RUN"]

        # 2. heartbeat rate within 10 % of heartbeat_hz (receive side, steady RUN)
        beats = [e["mono"] for e in commands if e["body"]["heartbeat"] and e["mono"] > t_steady]
        assert len(beats) >= 15
        rate = (len(beats) - 1) / (beats[-1] - beats[0])
        assert abs(rate - HZ) <= 0.1 * HZ, f"heartbeat {rate:.2f} Hz"

        # 3. the status queryable answers
        with open_session(BusConfig(cell=cell, connect=(f"tcp/127.0.0.1:{port}",))) as s:
            replies = list(s.get(BusKeys.of(f"workcell/{cell}/").status, timeout=3.0))
        status = json.loads(replies[0].ok.payload.to_bytes())
        assert status["state"] == "RUN" and status["config_hash"] == "h1"
        assert status["instance"] == "mon-test" and status["heartbeats"] >= 15

        # 4. a hung publisher (SIGSTOP: token stays until the lease) -> STOP by ttl
        n = len(watcher.events)
        os.kill(pub.pid, signal.SIGSTOP)
        t_hang = time.monotonic()
        stop = watcher.wait(lambda e: e["event"] == "verdict" and e["state"] == "STOP", start=n)
        assert stop is not None and stop["code"] == "ttl", stop
        assert stop["mono"] - t_hang <= TTL_MS / 1000 + 0.1
        assert all(e["event"] != "verdict" for e in watcher.events[n:watcher.events.index(stop)])
        n = len(watcher.events)
        os.kill(pub.pid, signal.SIGCONT)
        assert watcher.wait(lambda e: e["event"] == "verdict" and e["state"] == "RUN", start=n)

        # 5. a killed publisher -> STOP within ttl + 100 ms (the liveliness token vanishes)
        n = len(watcher.events)
        pub.kill()
        t_kill = time.monotonic()
        stop = watcher.wait(lambda e: e["event"] == "verdict" and e["state"] == "STOP", start=n)
        assert stop is not None and stop["code"] in ("liveliness", "ttl"), stop
        assert stop["mono"] - t_kill <= TTL_MS / 1000 + 0.1
    finally:
        if pub.is_alive():
            os.kill(pub.pid, signal.SIGCONT)
            pub.kill()
        pub.join(5)
        err = watcher.stop()
    # a clean exit; on a loaded machine the Zenoh close may outlast the 1.5 s shutdown
    # deadline, and then the forced exit (130) must say so (the deadline itself is tested in
    # tests/test_shutdown_bus.py)
    assert watcher.proc.returncode == 0 or (watcher.proc.returncode == 130
                                            and "exiting anyway" in err), err


def test_watch_without_monitor_reports_stop_and_exits_cleanly():
    port = free_port()
    with open_session(BusConfig(cell="nobody", listen=(f"tcp/127.0.0.1:{port}",))):
        out = subprocess.run(
            [sys.executable, "-m", "monitor", "watch", "--cell", "nobody",
             "--connect", f"tcp/127.0.0.1:{port}", "--duration", "0.5"],
            capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    assert "STOP" in out.stdout and "no command received yet" in out.stdout


def test_watch_says_where_it_looked_when_nothing_answers():
    """Silence is STOP on stdout; stderr says once where watch looked and what to try."""
    port = free_port()
    with open_session(BusConfig(cell="nobody", listen=(f"tcp/127.0.0.1:{port}",))):
        out = subprocess.run(
            [sys.executable, "-m", "monitor", "watch", "--cell", "nobody",
             "--connect", f"tcp/127.0.0.1:{port}", "--duration", "1.5", "--hint-after", "0.5"],
            capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    (line,) = [x for x in out.stderr.splitlines() if "nothing heard" in x] or [out.stderr]
    assert f"tcp/127.0.0.1:{port}" in line and "'nobody'" in line and "--connect" in line
    assert "--cell" in line and "monitor run" in line
    assert "STOP" in out.stdout


def test_bus_cli_errors_are_one_line():
    out = subprocess.run([sys.executable, "-m", "monitor", "watch", "--connect",
                          "nonsense-endpoint"], capture_output=True, text=True, timeout=30)
    assert out.returncode == 2
    assert out.stderr.startswith("monitor: error: ") and out.stderr.count("\n") == 1
    out = subprocess.run([sys.executable, "-m", "monitor", "router"],
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 2 and "--listen" in out.stderr


def test_router_status_and_reset_commands_through_a_router(tmp_path):
    """`monitor router` as the hub; the monitor and the CLI tools are clients of it. `monitor
    reset` waits for the monitor's answer: exit 0 accepted, 1 refused (with the reason)."""
    from monitor.bus.session import SafetyBus
    from monitor.policy import Command, Latch, ResetOutcome
    from monitor.wire.resets import LatchNonces

    port = free_port()
    router = subprocess.Popen(
        [sys.executable, "-m", "monitor", "router", "--listen", f"tcp/127.0.0.1:{port}"],
        stderr=subprocess.PIPE, text=True)
    client = ["--cell", "rt", "--mode", "client", "--connect", f"tcp/127.0.0.1:{port}"]
    key = tmp_path / "anna.key"
    keys = subprocess.run([sys.executable, "-m", "monitor", "keys", "new", str(key),
                           "--operator", "anna"], capture_output=True, text=True, timeout=30)
    assert keys.returncode == 0, keys.stderr
    operators = tmp_path / "operators"
    operators.write_text(keys.stdout.strip().splitlines()[-1] + "\n")  # "anna ed25519:..."

    def reset(*extra):
        return subprocess.Popen([sys.executable, "-m", "monitor", "reset", *client,
                                 "--operator", "anna", "--key", str(key), "--timeout", "10",
                                 *extra],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def next_request(bus):
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            got = bus.poll_resets()
            if got:
                return got[0]
            time.sleep(0.01)
        raise AssertionError("no reset request reached the monitor")

    try:
        assert "listening" in router.stderr.readline()
        cfg = BusConfig(cell="rt", instance="mon-rt", mode="client",
                        connect=(f"tcp/127.0.0.1:{port}",), operators_file=str(operators))
        with SafetyBus(cfg) as bus:
            bus.publish_command(Command("RUN", 1.0, ()))
            bus.update_status(fps=9.5)
            out = subprocess.run([sys.executable, "-m", "monitor", "status", "--json", *client],
                                 capture_output=True, text=True, timeout=30)
            assert out.returncode == 0, out.stderr
            status = json.loads(out.stdout)
            assert status["instance"] == "mon-rt" and status["fps"] == 9.5
            assert status["latch"] is None
            # not latched: nothing to reset, said by the CLI itself (exit 1), nothing sent
            out = subprocess.run([sys.executable, "-m", "monitor", "reset", *client,
                                  "--operator", "anna", "--key", str(key)],
                                 capture_output=True, text=True, timeout=30)
            assert out.returncode == 1 and "not latched" in out.stdout, out
            nonces = LatchNonces(bus.boot)
            latched = Command("STOP", 0.0, (), latched=True, latched_by=Latch(
                "protective_zone", "person 0 in P1", 1.0, nonce=nonces(1)))
            bus.publish_command(latched)
            # accepted by the policy -> exit 0; the CLI read the latch nonce and signed it
            proc = reset("--note", "cell checked")
            req = next_request(bus)
            assert (req.operator, req.note, req.confirm_clear) == ("anna", "cell checked", False)
            assert req.latch == nonces(1)
            bus.publish_command(Command("STOP", 0.0, (), reset=ResetOutcome(
                "anna", True, "reset accepted", req.request_id)))
            stdout, stderr = proc.communicate(timeout=30)
            assert proc.returncode == 0, stderr
            assert "accepted" in stdout
            # a new latch; refused by the policy -> exit 1 with the reason
            latched = dataclasses.replace(latched, latched_by=dataclasses.replace(
                latched.latched_by, nonce=nonces(2)))
            bus.publish_command(latched)
            proc = reset("--confirm-clear")
            req = next_request(bus)
            assert req.confirm_clear and req.latch == nonces(2)
            bus.publish_command(dataclasses.replace(latched, reset=ResetOutcome(
                "anna", False, "refused: person 0 in zone P1", req.request_id)))
            stdout, stderr = proc.communicate(timeout=30)
            assert proc.returncode == 1 and "REFUSED" in stdout and "person 0 in zone P1" in stdout
            # refused by the bus (no key for this operator) -> exit 1 with the reason
            out = subprocess.run([sys.executable, "-m", "monitor", "reset", *client,
                                  "--operator", "mallory"],
                                 capture_output=True, text=True, timeout=30)
            assert out.returncode == 1 and "unknown operator 'mallory'" in out.stdout
            assert bus.poll_resets() == []
        # no monitor any more: status and reset are one-line errors, exit 2, with a hint
        for cmd in ("status", "reset"):
            out = subprocess.run([sys.executable, "-m", "monitor", cmd, *client, "--timeout",
                                  "0.5", *(["--operator", "anna"] if cmd == "reset" else [])],
                                 capture_output=True, text=True, timeout=30)
            assert out.returncode == 2, out.stderr
            assert "no answer" in out.stderr or "no monitor answered" in out.stderr
            assert "--connect" in out.stderr
    finally:
        router.send_signal(signal.SIGTERM)
        router.communicate(timeout=10)
    assert router.returncode == 0


def test_the_demos_unsigned_reset_is_bound_to_the_latch_too(tmp_path):
    """The embedded demo accepts resets without operator keys: `monitor reset` still reads the
    latch nonce from the status and sends it, so the unsigned reset releases only that latch;
    a copy of it sent after the next latch is refused naming its stale nonce."""
    from monitor.bus.session import SafetyBus
    from monitor.policy import Command, Latch, ResetOutcome
    from monitor.wire.resets import LatchNonces, request_reset, reset_payload

    port = free_port()
    cfg = BusConfig(cell="demo", instance="mon-demo", listen=(f"tcp/127.0.0.1:{port}",),
                    allow_unsigned_resets=True)
    operator = f"demo-{os.getpid()}"  # no key file: sent unsigned
    with SafetyBus(cfg, startup_check_s=0.2) as bus:
        nonces = LatchNonces(bus.boot)
        bus.publish_command(Command("STOP", 0.0, (), latched=True, latched_by=Latch(
            "protective_zone", "person 0 in P1", 1.0, nonce=nonces(1))))
        proc = subprocess.Popen([sys.executable, "-m", "monitor", "reset", "--cell", "demo",
                                 "--connect", f"tcp/127.0.0.1:{port}", "--operator", operator,
                                 "--timeout", "10"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 20
        got: list = []
        while not got and time.monotonic() < deadline:
            got = bus.poll_resets()
            time.sleep(0.01)
        (req,) = got
        assert (req.operator, req.latch) == (operator, nonces(1))
        bus.publish_command(Command("RUN", 1.0, (), reset=ResetOutcome(
            operator, True, "reset accepted", req.request_id)))
        stdout, stderr = proc.communicate(timeout=30)
        assert proc.returncode == 0 and "accepted" in stdout, stderr
        assert "sending unsigned" in stderr
        # the next latch; the earlier unsigned request (as captured) sent again
        bus.publish_command(Command("STOP", 0.0, (), latched=True, latched_by=Latch(
            "protective_zone", "person 0 in P1", 5.0, nonce=nonces(2))))
        with open_session(BusConfig(cell="demo", instance="x",
                                    connect=(f"tcp/127.0.0.1:{port}",))) as peer:
            copy = reset_payload(operator, "copy-1", cell="demo", boot=bus.boot,
                                 latch=nonces(1))
            answer = None
            while answer is None and time.monotonic() < deadline:
                answer = request_reset(peer, BusKeys.of("workcell/demo/").reset, copy, None, 2.0)
        assert answer is not None and answer["accepted"] is False
        assert f"stale latch nonce {nonces(1)!r}" in answer["reason"]
        assert bus.poll_resets() == []


def test_watch_shows_the_latched_state_with_or_without_the_policys_details():
    from monitor.cli.watch import _latch_text

    assert _latch_text({"latched": False}) == ""
    assert _latch_text({"latched": True}) == "LATCHED"  # an older monitor: no details
    text = _latch_text({"latched": True, "reset_possible": True, "clear_for_s": 2.34,
                        "latched_by": {"code": "protective_zone",
                                       "message": "person 0 in robot-protective at 5.5 s"}})
    assert text == ("LATCHED by person 0 in robot-protective at 5.5 s; cell clear for 2.3 s: "
                    "reset possible (`monitor reset --operator <id>`)")
    assert _latch_text({"latched": True, "reset_possible": False, "latched_by": "junk",
                        "clear_for_s": "x"}) == "LATCHED: reset not possible yet"


@pytest.mark.parametrize("argv", [["watch"], ["reset"], ["status"], ["router"],
                                  ["bridge", "otus"], ["keys", "new"]])
def test_every_option_of_the_bus_commands_says_its_default(argv):
    import argparse

    from monitor.cli import build_parser

    parser = build_parser()
    for name in argv:
        parser = next(a for a in parser._actions
                      if isinstance(a, argparse._SubParsersAction)).choices[name]
    for action in parser._actions:
        if action.help in (None, argparse.SUPPRESS) or isinstance(action, argparse._HelpAction):
            continue
        if action.default == argparse.SUPPRESS:  # the global --debug flag, given anywhere
            continue
        assert "default" in action.help or "required" in action.help, \
            f"monitor {' '.join(argv)} {action.option_strings or action.dest}: {action.help}"
