"""`monitor run` as a real subprocess for the tests: a service with a Zenoh peer in the test
process (``Service``), a bare monitor with its log (``Monitor``), and their configs; and the bus
alone in the test process with an operator's session to it (``bus_with_operator``)."""

from __future__ import annotations

import contextlib
import json
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import zenoh

from monitor.adapters.follower import Follower
from monitor.bus.session import BusConfig, BusKeys, SafetyBus, open_session
from monitor.config import demo_cell_path
from monitor.scene import DemoScene
from monitor.wire.cell_consumer import CellWatchdog, subscribe_cell
from monitor.wire.consumer import Verdict
from monitor.wire.inbox import Inbox
from monitor.wire.resets import latch_of_status, reset_payload, signed_reset
from monitor.wire.signing import Signer, load_private_key, new_key_pair
from tests.helpers import free_port, note_wait

# The tests run beside other tests and load (benchmarks/suite_under_load.py), and a slow CI
# machine is not what they are about: no start-up capacity check in the monitors they start
# (about half a second of inference each; tests/test_capacity.py and tests/test_reaction.py
# test the check and the budget it feeds).
CAPACITY = 'capacity_check = "off"\n'
# A frame's age is judged when its step ends (frame_late): at a load of 8 on 2 cores a step
# takes 0.25-0.4 s, over the default max_frame_age (0.3 s). Tests not about frame age use 1 s.
LOAD_TOLERANT_AGE = "max_frame_age = 1.0\n"


# One inference thread in every monitor a test starts: the suite's three workers already keep both
# cores busy, and a second onnxruntime thread each only adds waiting (synthetic model, 2-core
# Xeon: 85 ms of CPU a frame on one thread, 123 ms on two). Tests about threads set their own.
ONE_THREAD = "threads = 1\n"
# At most 5 frames a second in every one-camera monitor a test starts, unless the test sets its
# own: a looped 15 fps video otherwise runs inference as fast as one thread allows (~12 frames
# a second, a whole core) for nothing a test checks, beside the other workers' tests.
TEST_FPS = "max_fps = 5\n"


def with_default(config: str, section: str, line: str) -> str:
    """A monitor.toml text with ``line`` (``key = value``) in ``[section]``, unless the text
    sets that key itself (a test about it keeps its own value)."""
    key = line.split("=", 1)[0].strip()
    if f"{key} =" in config:
        return config
    if f"[{section}]\n" in config:
        return config.replace(f"[{section}]\n", f"[{section}]\n{line}", 1)
    return config + f"\n[{section}]\n{line}"


def one_inference_thread(config: str) -> str:
    """A monitor.toml text with ``[detector] threads = 1`` unless it sets its own threads."""
    return with_default(config, "detector", ONE_THREAD)


# onnxruntime, the reference backend, in every monitor a Service starts unless the test names
# its own: these tests check the loop, and `auto` would first measure every backend the host
# has (and then the envelope with the chosen one) for each new model file, which on a loaded
# host comes in front of the bus opening; tests/test_backends.py checks `auto` in `monitor run`
REFERENCE_BACKEND = 'backend = "onnxruntime"\n'


def reference_backend(config: str) -> str:
    """A monitor.toml text with ``[detector] backend = "onnxruntime"`` unless it names one."""
    return with_default(config, "detector", REFERENCE_BACKEND)


def capped_rate(config: str) -> str:
    """A monitor.toml text whose one ``[camera]`` is processed at most ``TEST_FPS`` times a
    second, unless it sets its own ``max_fps`` (configs with ``[[camera]]`` are left alone)."""
    if "[camera]\n" not in config or "[[camera" in config:
        return config
    return with_default(config, "camera", TEST_FPS)


def _load_tolerant(extra: str) -> str:
    """``extra`` with ``[policy] max_frame_age = 1.0`` unless it sets its own."""
    return with_default(extra, "policy", LOAD_TOLERANT_AGE)


def wait_for(cond: Callable[[], object], timeout: float, what: str, proc=None):
    """Poll until ``cond()`` is truthy; fail with the service's log if it died or timed out."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        value = cond()
        if value:
            note_wait(what, time.monotonic() - t0, timeout)
            return value
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"service exited ({proc.poll()}) waiting for {what}: "
                                 f"{proc.log()}")
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}" + (f": {proc.log()}" if proc else ""))


def summary_of(commands: list[dict]) -> list[tuple]:
    """(seq, state, reason codes) at each change, for failure messages."""
    out, prev = [], None
    for c in commands:
        key = (c["state"], tuple(r["code"] for r in c["reasons"]))
        if key != prev:
            out.append((c["seq"], *key))
            prev = key
    return out


class Service:
    """`monitor run --config <tmp>/monitor.toml --log-json` and a Zenoh peer in this process
    connected to it, recording commands, detections and the liveliness token."""

    def __init__(self, tmp: Path, model: Path, camera: str, extra: str = "",
                 allow_test_model: bool = False, camera_lines: str = "") -> None:
        self.bus_port, self.metrics_port = free_port(), free_port()
        self.keys = BusKeys.of("workcell/t5/")
        # a real operator key: the monitor refuses unsigned resets from a config file
        from monitor.wire.signing import load_private_key, new_key_pair

        private, _, public = new_key_pair(tmp / "tester.key")
        self.operator = load_private_key(private)
        (tmp / "operators").write_text(f"tester {public}\n")
        self.config = tmp / "monitor.toml"
        extra = _load_tolerant(extra)
        self.config.write_text(reference_backend(capped_rate(one_inference_thread(
            f'[camera]\nsource = "{camera}"\n{camera_lines}'
            f'[model]\npath = "{model}"\n'
            + ("allow_test_model = true\n" if allow_test_model else "")
            + f'[bus]\ncell = "t5"\ninstance = "svc-test"\noperators_file = "operators"\n'
            f'listen = ["tcp/127.0.0.1:{self.bus_port}"]\n'
            f'[service]\nmetrics_port = {self.metrics_port}\n{CAPACITY}' + extra))))
        self.stderr_path = tmp / "service.log"
        self.commands: list[dict] = []
        self.detections: list[dict] = []
        self.alive: list[bool] = []

    def log(self) -> str:
        return (f"received {summary_of(self.commands)[-12:]}; log: "
                + self.stderr_path.read_text()[-2000:])

    def poll(self):
        return self.proc.poll()

    def __enter__(self) -> Service:
        self._err = self.stderr_path.open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "monitor", "run", "--config", str(self.config), "--log-json"],
            stdout=subprocess.DEVNULL, stderr=self._err)
        try:
            wait_for(self._listening, 60, "the bus port", self)
            cfg = BusConfig(cell="t5", instance="test-peer",
                            connect=(f"tcp/127.0.0.1:{self.bus_port}",))
            self.session = open_session(cfg)  # a second process: this test
            s = self.session
            s.declare_subscriber(self.keys.command, lambda x: self.commands.append(
                json.loads(x.payload.to_bytes())))
            s.declare_subscriber(self.keys.detections, lambda x: self.detections.append(
                json.loads(x.payload.to_bytes())))
            s.liveliness().declare_subscriber(
                self.keys.alive + "/*", lambda x: self.alive.append(
                    x.kind == zenoh.SampleKind.PUT), history=True)
        except BaseException:
            self._kill()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.session.close()
        self._kill()

    def _kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        self._err.close()

    def _listening(self) -> bool:
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", self.bus_port)) == 0

    def stop(self, sig: int) -> int:
        self.proc.send_signal(sig)
        return self.proc.wait(20)

    def assert_stops_cleanly(self, sig: int) -> None:
        """``sig`` ends the service with a final STOP: exit 0, or 128 + sig when a loaded host
        needed more than the signal's grace (1.5 s) to wind down and the forced exit published
        that STOP itself (monitor/signals.py)."""
        code = self.stop(sig)
        log = self.stderr_path.read_text()
        forced = code == 128 + sig and "did not stop within" in log
        assert code == 0 or forced, f"exit {code}: {log[-2000:]}"
        wait_for(lambda: self.commands and self.commands[-1]["state"] == "STOP"
                 and any(r["code"] == "shutdown" for r in self.commands[-1]["reasons"]),
                 10, "the final shutdown STOP")

    def next_command(self, start: int, pred: Callable[[dict], bool], timeout: float, what: str
                     ) -> tuple[int, dict]:
        """The first command at index >= ``start`` of the received list matching ``pred``."""
        def find():
            for i in range(start, len(self.commands)):
                if pred(self.commands[i]):
                    return i, self.commands[i]
            return None
        return wait_for(find, timeout, what, self)

    def reach(self, start: int, pred: Callable[[dict], bool], timeout: float, what: str
              ) -> tuple[int, dict]:
        """``next_command``, but a STOP latched on the way is reset, as an operator would, once
        the monitor says reset is possible. On a loaded host the monitor is right to latch for
        a stall or late frames; a test whose subject is not the latch waits past it this way."""
        sent: set[str] = set()

        def find():
            for i in range(start, len(self.commands)):
                if pred(self.commands[i]):
                    return i, self.commands[i]
            self.release_latch(sent)
            return None
        return wait_for(find, timeout, what, self)

    def release_latch(self, sent: set[str]) -> None:
        """Reset the latched STOP once the monitor says a reset is possible, as an operator
        would (once per latch: ``sent`` keeps the latches already reset)."""
        last = self.commands[-1] if self.commands else {}
        if last.get("latched") and last.get("reset_possible"):
            boot, latch = latch_of_status(self.status())
            if latch and latch not in sent:
                sent.add(latch)
                payload = reset_payload("tester", f"load-{len(sent)}", cell="t5", boot=boot,
                                        latch=latch)
                self.session.put(self.keys.reset, payload, attachment=signed_reset(
                    self.operator, self.keys.reset, payload))

    def status(self) -> dict:
        replies = list(self.session.get(self.keys.status, timeout=3.0))
        assert len(replies) == 1 and replies[0].ok is not None
        return json.loads(replies[0].ok.payload.to_bytes())


def codes(command: dict) -> set[str]:
    return {r["code"] for r in command["reasons"]}


GONE_WITHIN_S = 2.0


def empty_cell_video(path: Path, frames: int = 15) -> Path:
    """The first second of the demo scene (nobody in the cell yet), to be looped."""
    writer = None
    for _, (image, truth) in zip(range(frames), DemoScene().frames(), strict=False):
        if truth.persons:
            raise AssertionError("the demo scene has a person in its first second")
        if writer is None:
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 15,
                                     (image.shape[1], image.shape[0]))
        writer.write(image)
    writer.release()
    return path


def write_config(tmp: Path, model: Path, extra: str = "") -> tuple[Path, int]:
    """monitor.toml: the looped empty cell, the demo zones, a free loopback port."""
    video = empty_cell_video(tmp / "empty-cell.mp4")
    port = free_port()
    config = tmp / "monitor.toml"
    config.write_text(capped_rate(one_inference_thread(
        f'[camera]\nsource = "{video}"\nloop = true\nrealtime = true\n'
        f'[model]\npath = "{model}"\n'
        f'[zones]\nfile = "{demo_cell_path()}"\n'
        f'[service]\n{CAPACITY}'
        f'[bus]\ncell = "t6"\ninstance = "shutdown-test"\n'
        f'listen = ["tcp/127.0.0.1:{port}"]\n' + extra)))
    return config, port


class Monitor:
    """`monitor run --config ... --log-json` as a subprocess, its log in a file."""

    def __init__(self, config: Path, port: int, log: Path) -> None:
        self.port = port
        self.log_path = log
        self._log = log.open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "monitor", "run", "--config", str(config), "--log-json"],
            stdout=subprocess.DEVNULL, stderr=self._log)

    def events(self) -> list[str]:
        out = []
        for line in self.log_path.read_text().splitlines():
            try:
                out.append(json.loads(line)["event"])
            except (ValueError, KeyError):
                out.append(line)
        return out

    def poll(self) -> int | None:
        return self.proc.poll()

    def log(self) -> str:
        return self.log_path.read_text()[-2000:]

    def wait_for(self, cond, timeout: float, what: str):
        """Poll until ``cond()`` is truthy; fail with the log if the monitor died or timed out."""
        return wait_for(cond, timeout, what, self)

    def listening(self) -> bool:
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", self.port)) == 0

    def signal_and_time(self, *signals: tuple[int, float]) -> float:
        """Send each (signal, delay before it); seconds from the first signal to exit."""
        first = None
        for sig, delay in signals:
            if delay:
                time.sleep(delay)  # the gap between two signals is what is tested
            if self.proc.poll() is None:
                self.proc.send_signal(sig)
            first = first or time.monotonic()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(GONE_WITHIN_S + 3.0)
        return (time.monotonic() - first) if self.proc.poll() is not None else float("inf")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        self._log.close()


class CellConsumer:
    """The consumer rule for a cell of several monitors (CellWatchdog), in this process, over
    the router at ``router``."""

    def __init__(self, router: int, expected: dict, cell: str) -> None:
        prefix = f"workcell/{cell}/"
        self.session = open_session(BusConfig(cell=cell, instance="consumer",
                                              connect=(f"tcp/127.0.0.1:{router}",)))
        self.dog = CellWatchdog(expected, prefix, cell=cell)
        self.inbox = Inbox(256)
        self.entities = subscribe_cell(self.session, prefix, self.inbox)
        self.follower = Follower(self.dog, self.inbox)
        self.seen: list[tuple[str, str]] = []

    def verdict(self) -> Verdict:
        self.follower.drain(0.0)
        v = self.dog.verdict(time.monotonic())
        if not self.seen or self.seen[-1] != (v.state, v.reason):
            self.seen.append((v.state, v.reason))
        return v

    def wait(self, pred, timeout: float, what: str, proc=None) -> Verdict:
        try:
            return wait_for(lambda: (v := self.verdict()) and pred(v) and v, timeout, what, proc)
        except AssertionError as exc:
            raise AssertionError(f"{exc}; verdicts seen: {self.seen[-8:]}") from None

    def close(self) -> None:
        self.session.close()


@contextlib.contextmanager
def bus_with_operator(folder: Path, cell: str, instance: str, answer_s: float):
    """A real SafetyBus on 127.0.0.1 that signs with ``folder/monitor.key`` (its public key:
    ``folder/monitor.key.pub``) and lists anna in its operators file, and anna's own Zenoh
    session to it: (bus, session, anna's Signer). ``answer_s``: the bus's deadline for the
    pipeline's answer (``reset_answer_s``)."""
    private, _, public = new_key_pair(folder / "anna.key")
    (folder / "operators").write_text(f"anna {public}\n")
    monitor_key, _, _ = new_key_pair(folder / "monitor.key")
    port = free_port()
    cfg = BusConfig(cell=cell, instance=instance, listen=(f"tcp/127.0.0.1:{port}",),
                    signing_key=str(monitor_key), operators_file=str(folder / "operators"),
                    reset_answer_s=answer_s)
    with SafetyBus(cfg) as bus, open_session(BusConfig(
            cell=cell, instance="anna", connect=(f"tcp/127.0.0.1:{port}",))) as session:
        anna: Signer = load_private_key(private)
        yield bus, session, anna
