"""Small helpers shared by the test files (one copy each): loopback ports, polling, and the
checks that an error is one clear line."""

from __future__ import annotations

import contextlib
import inspect
import io
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import cv2
import numpy as np

T = TypeVar("T")


def run_monitor(*args: object, timeout: float = 120, cwd: Path | None = None
                ) -> subprocess.CompletedProcess:
    """``python -m monitor ARGS`` in a fresh process (what a user types), output as text."""
    return subprocess.run([sys.executable, "-m", "monitor", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


def run_here(*args: object, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """The same command as ``run_monitor``, in this process: the ``main`` a fresh process runs,
    with its exit code and output, without a fresh interpreter's start-up (about 1.5 s of
    CPU). For commands that end by themselves and need no process of their own: file edits,
    listings, refusals. A traceback escaping ``main`` fails the test where it happens."""
    from monitor import cli

    out, err = io.StringIO(), io.StringIO()
    with contextlib.ExitStack() as stack:
        if cwd is not None:
            stack.enter_context(contextlib.chdir(cwd))
        stack.enter_context(contextlib.redirect_stdout(out))
        stack.enter_context(contextlib.redirect_stderr(err))
        try:
            code = cli.main([str(a) for a in args])
        except SystemExit as exc:  # argparse's usage errors exit 2, as in a fresh process
            code = exc.code if isinstance(exc.code, int) else 1
    return subprocess.CompletedProcess(["monitor", *map(str, args)], code, out.getvalue(),
                                       err.getvalue())


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A free TCP (or UDP) port on 127.0.0.1: tests use loopback only."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# How long a wait may take before the test fails: a ceiling, not a delay (a wait returns as soon
# as its event arrives). Things that take 0.1 s on a quiet machine take 1-4 s on a crushed one
# (benchmarks/suite_under_load.py --load 20); a ceiling of 30 s costs nothing when all is well.
WAIT_CEILING = 30.0


def describe(cond: Callable[[], object]) -> str:
    """The source text of ``cond`` (a lambda: its body) for a failure message."""
    try:
        text = " ".join(line.strip() for line in inspect.getsource(cond).splitlines())
    except (OSError, TypeError):
        return getattr(cond, "__qualname__", repr(cond))
    if "lambda" in text:
        text = text[text.index("lambda"):]
    return text[:200]


def note_wait(what: str, waited: float, ceiling: float) -> None:
    """A wait that took over half its ceiling, written where benchmarks/suite_under_load.py
    collects them (``MONITOR_TEST_WAITS``, a directory): the tests closest to a timeout."""
    folder = os.environ.get("MONITOR_TEST_WAITS")
    if not folder or waited <= ceiling / 2:
        return
    test = os.environ.get("PYTEST_CURRENT_TEST", "?").rsplit(" (", 1)[0]
    line = json.dumps({"test": test, "what": what, "waited": round(waited, 2),
                       "ceiling": ceiling})
    with open(Path(folder) / f"waits-{os.getpid()}.jsonl", "a") as f:
        f.write(line + "\n")


def wait_for(cond: Callable[[], T], timeout: float = WAIT_CEILING,
             what: str | Callable[[], object] = "") -> T:
    """Poll ``cond()`` every 5 ms until it is truthy (its answer); after ``timeout`` s fail,
    naming what did not arrive (``what``, or ``cond``'s source; a callable ``what`` adds
    what it returns then, e.g. the last messages seen)."""
    t0 = time.monotonic()
    while True:
        value = cond()
        waited = time.monotonic() - t0
        if value:
            note_wait(what if isinstance(what, str) and what else describe(cond), waited,
                      timeout)
            return value
        if waited >= timeout:
            break
        time.sleep(0.005)
    name = describe(cond) if callable(what) or not what else what
    detail = f" (then: {what()!r})" if callable(what) else ""
    raise AssertionError(f"did not arrive within {timeout:g} s: {name}{detail}")


def put_until(put_round: Callable[[], None], arrived: Callable[[], T],
              what: str | Callable[[], object], every: float = 0.5,
              timeout: float = WAIT_CEILING) -> T:
    """Run ``put_round`` now and every ``every`` s until ``arrived()``: a new subscription
    reaches the other clients through the router a moment after it is declared (longer on a
    loaded host), and a put made before that goes nowhere. Puts that must be refused belong in
    the same round, so they are repeated as often as the allowed ones."""
    last = [-every]

    def cond() -> T:
        if time.monotonic() - last[0] >= every:
            put_round()
            last[0] = time.monotonic()
        return arrived()
    return wait_for(cond, timeout=timeout, what=what)


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


def protective_walk(fps: float):
    """A basic walk into the protective zone (2 x 2 m around the robot), a pause, and out:
    (scene, cell) of the generated cell scene (tests of the model's envelope)."""
    from monitor.replay import scenarios as sc
    from monitor.scene import cell as scene_cell
    from monitor.zones import parse_cell

    walker = scene_cell.Walker(((0.0, -2.6, -0.8), (2.0, -0.2, -0.4), (3.5, -0.2, -0.4),
                                (5.5, -2.6, -0.8)))
    scene = scene_cell.CellScene((walker,), fps=fps, duration_s=6.0)
    return scene, parse_cell(sc.Scenario("walk", "walk in", scene).zone_data())


def commissioner_key(folder: Path, name: str = "anna") -> Path:
    """A commissioner's key pair in ``folder`` and the line for ``folder/commissioners``
    (appended; ``[service] commissioners_file = "commissioners"`` names it); the private key."""
    from monitor.wire.signing import new_key_pair

    private, _, public = new_key_pair(Path(folder) / f"{name}-commissioner.key")
    with (Path(folder) / "commissioners").open("a") as fh:
        fh.write(f"{name} {public}\n")
    return private


def live_frame(background: np.ndarray, i: int) -> np.ndarray:
    """Frame ``i`` of a live camera looking at ``background``: its own sensor noise (0..5
    grey levels, seeded by ``i``), so consecutive frames differ by about 1 grey level at the
    health checks' analysis size, as a real camera's do (a repeated picture is frozen)."""
    noise = np.random.default_rng(i).integers(0, 6, background.shape, dtype=np.uint8)
    return cv2.add(background, noise)
