"""`monitor watch`, `router` and `bridge otus` end within 2 s of SIGTERM/SIGINT in every phase.

Phases: right after the process starts (before our handlers exist), late in start-up while
it opens its Zenoh session (70-100 % of the measured time-to-ready, under CPU load from a
busy-loop helper), and while it runs. A second signal 0.1 s after the first ends it at once.
benchmarks/shutdown.py repeats this 20 times per case and prints a table.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import random
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

from tests.helpers import free_port

LIMIT_S = 2.0
_READY_S: dict[str, float] = {}  # last measured start-up time per command (s)



def command(name: str) -> tuple[list[str], str]:
    """argv and the stderr text that says the command is up and running."""
    port = free_port()
    if name == "watch":
        return ["watch", "--connect", f"tcp/127.0.0.1:{port}"], "NOT authenticated"
    if name == "router":
        return ["router", "--listen", f"tcp/127.0.0.1:{port}"], "listening"
    return (["bridge", "otus", "--listen", f"127.0.0.1:{free_port(socket.SOCK_DGRAM)}",
             "--zenoh-listen", f"tcp/127.0.0.1:{port}"], "UDP")


def busy_loop() -> None:
    while True:
        pass


@contextlib.contextmanager
def cpu_load():
    p = multiprocessing.get_context("spawn").Process(target=busy_loop, daemon=True)
    p.start()
    try:
        yield
    finally:
        p.kill()
        p.join(5)


def stop_time(name: str, phase: str, second: bool, rng: random.Random) -> tuple[float, str]:
    """Seconds from the first signal until the process is gone, and its stderr."""
    argv, ready = command(name)
    proc = subprocess.Popen([sys.executable, "-m", "monitor", *argv], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    up = threading.Event()
    err: list[str] = []

    def read() -> None:
        for line in proc.stderr:
            err.append(line)
            if ready in line:
                up.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    started = time.monotonic()
    sig = signal.SIGTERM
    if phase == "opening":
        # late in start-up, where the Zenoh session opens: 70-100 % of the last time-to-ready
        time.sleep(rng.uniform(0.7, 1.0) * _READY_S.get(name, 1.0))
    elif phase == "running":
        if not up.wait(60):
            proc.kill()
            raise AssertionError(f"{name} never came up: {''.join(err)}")
        _READY_S[name] = time.monotonic() - started
        sig = rng.choice((signal.SIGTERM, signal.SIGINT))
    t0 = time.monotonic()
    proc.send_signal(sig)
    if second:
        time.sleep(0.1)
        if proc.poll() is None:
            proc.send_signal(sig)
    try:
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    gone = time.monotonic() - t0
    reader.join(5)
    return gone, "".join(err)


@pytest.mark.slow
@pytest.mark.parametrize("second", [False, True], ids=["one-signal", "two-signals"])
@pytest.mark.parametrize("phase", ["running", "start", "opening"])
def test_bus_commands_stop_within_two_seconds(phase, second):
    names = ("watch", "router", "bridge")
    results: dict[str, tuple[float, str]] = {}

    def one(name: str) -> None:  # the three commands at once: the suite stays short
        results[name] = stop_time(name, phase, second, random.Random(f"{phase}{second}{name}"))

    with cpu_load():
        threads = [threading.Thread(target=one, args=(n,)) for n in names]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
    assert sorted(results) == sorted(names)
    for name, (gone, err) in results.items():
        assert gone <= LIMIT_S, f"{name} took {gone:.2f} s after the signal: {err}"
        assert "Traceback" not in err and ".rs:" not in err, err


@pytest.mark.slow
def test_a_running_watch_stops_cleanly_with_exit_0():
    argv, ready = command("watch")
    proc = subprocess.Popen([sys.executable, "-m", "monitor", *argv, "--every", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert ready in proc.stderr.readline()
    first = proc.stdout.readline()
    assert "STOP" in first and "no command received yet" in first
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "did not stop" not in err
