"""Several monitors on one cell, for real: a `monitor router`, two `monitor run` processes with
the roles monitor-a and monitor-b (each its own MJPEG camera and its own key), and the consumer
rule (CellWatchdog) in this process over real Zenoh. The cell RUNs only when both say RUN;
a stopped camera, a frozen or killed monitor, a duplicate or an unknown third monitor is STOP
by name; a reset goes to both latched monitors."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from monitor.bus.session import BusKeys
from monitor.wire.signing import load_public_key, new_key_pair
from tests.cameras import MjpegCamera, demo_jpegs
from tests.helpers import free_port
from tests.processes import CAPACITY, CellConsumer, Monitor, one_inference_thread, wait_for

CELL = "tc"
PREFIX = f"workcell/{CELL}/"


def _config(tmp: Path, role: str, camera: str, router: int, instance: str | None = None
            ) -> Path:
    key = tmp / f"{role}.key"
    if not key.exists():
        new_key_pair(key)
    config = tmp / f"{instance or role}.toml"
    config.write_text(one_inference_thread(
        # 4 frames a second: three monitors, a router and the cameras share 2 cores here
        f'[camera]\nsource = "{camera}"\nmax_fps = 4.0\n'
        '[model]\nallow_test_model = true\npath = "MODEL"\n'
        '[zones]\nallow_no_protective = true\n'
        '[policy]\nframe_timeout = 1.0\nmax_frame_age = 1.0\n'
        f'[service]\n{CAPACITY}'
        f'[bus]\ncell = "{CELL}"\nrole = "{role}"\ninstance = "{instance or role}"\n'
        f'signing_key = "{key}"\noperators_file = "operators"\n'
        f'connect = ["tcp/127.0.0.1:{router}"]\n'))
    return config


def _reset(tmp: Path, router: int) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "monitor", "reset", "--operator", "tester", "--key",
         str(tmp / "tester.key"), "--cell", CELL, "--connect", f"tcp/127.0.0.1:{router}",
         "--role", "monitor-a", "--role", "monitor-b", "--timeout", "8"],
        capture_output=True, text=True, timeout=60)


@pytest.mark.slow
def test_two_monitors_one_cell_run_only_together_and_every_fault_is_named(
        tmp_path, synthetic_model):
    router_port = free_port()
    _, _, public = new_key_pair(tmp_path / "tester.key")
    (tmp_path / "operators").write_text(f"tester {public}\n")
    router = subprocess.Popen([sys.executable, "-m", "monitor", "router", "--listen",
                               f"tcp/127.0.0.1:{router_port}"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs: list[Monitor] = []
    consumer = None

    def start(role: str, url: str, instance: str | None = None) -> Monitor:
        config = _config(tmp_path, role, url, router_port, instance)
        config.write_text(config.read_text().replace("MODEL", str(synthetic_model)))
        mon = Monitor(config, 0, tmp_path / f"{instance or role}.log")
        procs.append(mon)
        return mon

    def recover(what: str) -> None:
        """RUN again: a stall of this loaded machine (a third process loading its model)
        latches a monitor's STOP, which then needs the operator's reset, like on site."""
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            try:
                consumer.wait(lambda v: v.state == "RUN", 3, what)
                return
            except AssertionError:
                _reset(tmp_path, router_port)
        consumer.wait(lambda v: v.state == "RUN", 1, what)

    try:
        with MjpegCamera(demo_jpegs()) as cam_a, MjpegCamera(demo_jpegs()) as cam_b:
            a = start("monitor-a", cam_a.url)
            b = start("monitor-b", cam_b.url)
            expected = {r: (load_public_key(tmp_path / f"{r}.key.pub"),)
                        for r in ("monitor-a", "monitor-b")}
            consumer = CellConsumer(router_port, expected, CELL)
            # both up (a verdict from each), then RUN; a loaded machine may latch a STOP while
            # the other monitor loads its model (frame_late): the operator's reset, as later
            wait_for(lambda: all(any(e.startswith("command") for e in m.events())
                                 for m in (a, b)), 120, "a decision from both monitors")
            recover("RUN from both monitors")

            # --- an unknown third monitor with its own key on the cell: STOP, named -------
            c = start("monitor-c", cam_a.url)
            v = consumer.wait(lambda v: v.code == "unknown_monitor", 90, "unknown monitor-c", c)
            assert v.state == "STOP" and "monitor-c" in v.reason
            c.proc.kill()
            c.proc.wait(10)
            recover("RUN after monitor-c left")

            # --- a second monitor-a: refused at start, and a live duplicate is STOP, named -
            dup = start("monitor-a", cam_a.url, instance="monitor-a-2")
            # refused at start (it saw monitor-a's token within its start-up check), or, when a
            # loaded machine connected it after that check, the two see each other live and
            # the cell STOPs, named (the documented late-duplicate rule): whichever comes first
            wait_for(lambda: dup.proc.poll() is not None
                     or consumer.verdict().code == "duplicate_monitor", 90,
                     "the duplicate refused or seen")
            if dup.proc.poll() is not None:
                assert dup.proc.returncode != 0
                assert "already live on cell 'tc' as 'monitor-a'" in dup.log()
            else:
                v = consumer.wait(lambda v: v.code == "duplicate_monitor", 30, "late dup", a)
                assert v.state == "STOP" and "monitor-a" in v.reason
                dup.proc.kill()
                dup.proc.wait(10)
                recover("RUN after the late duplicate left")
            token = consumer.session.liveliness().declare_token(
                BusKeys.of(PREFIX, "monitor-a").alive + "/monitor-a-2")
            v = consumer.wait(lambda v: v.code == "duplicate_monitor", 30, "duplicate a", a)
            assert v.state == "STOP" and v.reason.startswith("monitor-a: duplicate_monitor")
            token.undeclare()
            recover("RUN after the duplicate left")

            # --- one monitor's own STOP is the cell's; a reset goes to both latched -------
            cam_b.online.clear()
            # monitor-b's own STOP is named; on a loaded machine monitor-a may STOP too (a
            # stall, a late duplicate check), named as well, and monitor-b's first STOP may be
            # a stall ("pipeline handed in no command") before its camera's loss
            consumer.wait(lambda v: v.state == "STOP" and "monitor-b:" in v.reason
                          and "camera" in v.reason.split("monitor-b:", 1)[1], 30,
                          "monitor-b's STOP naming its camera", b)
            named = len(consumer.seen) - 1
            cam_a.online.clear()
            consumer.wait(lambda v: "monitor-a:" in v.reason and "monitor-b:" in v.reason,
                          30, "STOP from both", a)
            # from monitor-b's STOP on: never a RUN
            assert all(state == "STOP" for state, _ in consumer.seen[named:]), \
                consumer.seen[named:]
            refused = _reset(tmp_path, router_port)  # the cameras are still away
            assert refused.returncode == 1, refused.stdout + refused.stderr
            assert "monitor-a: reset by tester REFUSED" in refused.stdout
            assert "monitor-b: reset by tester REFUSED" in refused.stdout
            cam_a.online.set()
            cam_b.online.set()
            deadline = time.monotonic() + 60
            accepted: set[str] = set()
            while True:  # frames come back after the grabbers' backoff, one camera first:
                # a monitor that accepted an earlier try answers "not latched" to the next
                done = _reset(tmp_path, router_port)
                accepted |= {r for r in ("monitor-a", "monitor-b")
                             if f"{r}: reset by tester accepted" in done.stdout}
                if done.returncode == 0 or time.monotonic() > deadline:
                    break
                time.sleep(1.0)
            assert done.returncode == 0, done.stdout + done.stderr
            assert accepted == {"monitor-a", "monitor-b"}, done.stdout
            consumer.wait(lambda v: v.state == "RUN", 60, "RUN after both resets", a)

            # --- a frozen monitor, then a killed one: STOP, named ------------------------
            b.proc.send_signal(signal.SIGSTOP)
            try:
                # b's silence is named (a loaded machine may stall monitor-a too, named
                # as well; b's last RUN holds until its ttl runs out)
                v = consumer.wait(lambda v: "monitor-b: silence" in v.reason, 30,
                                  "STOP, b frozen")
                assert v.state == "STOP"
            finally:
                b.proc.send_signal(signal.SIGCONT)
            a.proc.kill()
            v = consumer.wait(lambda v: "monitor-a: silence" in v.reason, 30, "a killed")
            assert v.state == "STOP"
    finally:
        if consumer is not None:
            consumer.close()
        for mon in procs:
            mon.close()
        router.kill()
        router.wait(10)


def test_a_role_monitor_keeps_single_monitor_keys_apart(tmp_path):
    """A role's monitor does not see the cell's role-less token as its duplicate, and the
    consumer of a single monitor (CommandWatchdog on safety/command) never hears roles."""
    assert BusKeys.of(PREFIX, "monitor-a").alive + "/x" != BusKeys.of(PREFIX).alive + "/x"
    assert zenoh.KeyExpr(BusKeys.of(PREFIX).alive + "/*").intersects(
        zenoh.KeyExpr(BusKeys.of(PREFIX, "monitor-a").alive + "/i")) is False
    assert zenoh.KeyExpr(BusKeys.of(PREFIX).command).intersects(
        zenoh.KeyExpr(BusKeys.of(PREFIX, "monitor-a").command)) is False
