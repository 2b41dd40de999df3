"""Small helpers shared by the test files (one copy each): loopback ports, polling, and the
checks that an error is one clear line."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

T = TypeVar("T")


def run_monitor(*args: object, timeout: float = 120, cwd: Path | None = None
                ) -> subprocess.CompletedProcess:
    """``python -m monitor ARGS`` in a fresh process (what a user types), output as text."""
    return subprocess.run([sys.executable, "-m", "monitor", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A free TCP (or UDP) port on 127.0.0.1: tests use loopback only."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(cond: Callable[[], T], timeout: float = 3.0) -> T:
    """Poll ``cond()`` every 5 ms until it is truthy or ``timeout`` s pass; its last answer."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(0.005)
    return cond()


def assert_one_line(exc: BaseException, *needles: str) -> None:
    text = str(exc)
    assert "\n" not in text and text.strip() == text and text
    for needle in needles:
        assert needle in text, f"{needle!r} not in {text!r}"


def assert_one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("monitor: error:")]
    assert len(errors) == 1, proc.stderr
    # FFmpeg/OpenCV may log before it; our message is the last line
    assert proc.stderr.rstrip("\n").splitlines()[-1] == errors[0]
    for needle in needles:
        assert needle in errors[0], f"{needle!r} not in {errors[0]!r}"
    return errors[0]


def zones_cli(*args: object) -> int:
    """``monitor zones ARGS`` in this process (its exit code)."""
    from monitor import cli

    return cli.main(["zones", *map(str, args)])


def one_error_line(capsys) -> str:
    """The one error line a command in this process wrote (warnings of earlier, successful
    edits may come before it)."""
    lines = capsys.readouterr().err.strip().splitlines()
    errors = [ln for ln in lines if not ln.startswith("monitor: warning: ")]
    assert len(errors) == 1 and errors[0].startswith("monitor: error: "), lines
    return errors[0]
