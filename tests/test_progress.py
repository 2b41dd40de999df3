"""Progress on a terminal, silence in logs: the CLI's long steps (model build, replay) draw a
bar on stderr when it is a terminal (a pseudo-terminal here) and print nothing but their result
lines when it is not (a log file, CI)."""

from __future__ import annotations

import fcntl
import os
import pty
import select
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest

from monitor.scene import DemoScene, write_video

ROOT = Path(__file__).resolve().parents[1]


def _env(home: Path) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT), WORKCELL_MONITOR_HOME=str(home),
               COLUMNS="100")
    env.pop("TERM", None)
    return env


def run_on_terminal(args: list[str], home: Path, timeout: float = 120.0,
                    until: str | None = None) -> tuple[int | None, str]:
    """Run ``python -m monitor ARGS`` with stderr on a pseudo-terminal (stdout a pipe);
    returns (exit code, what the terminal showed). ``until``: stop the command once the
    terminal shows this (exit code None)."""
    leader, follower = pty.openpty()
    # a real terminal has a size (a 0x0 one gets no bar from tqdm)
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    proc = subprocess.Popen([sys.executable, "-m", "monitor", *args], cwd=ROOT,
                            env=_env(home), stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=follower)
    os.close(follower)
    shown = bytearray()
    try:
        while True:
            ready, _, _ = select.select([leader], [], [], timeout)
            if not ready:
                proc.kill()
                raise AssertionError(f"no output for {timeout} s: {bytes(shown)!r}")
            try:
                chunk = os.read(leader, 4096)
            except OSError:  # EIO: the child closed the terminal
                break
            if not chunk:
                break
            shown += chunk
            if until is not None and until.encode() in shown:
                proc.kill()
                proc.wait(timeout)
                return None, shown.decode(errors="replace")
        proc.stdout.read()
        code = proc.wait(timeout)
    finally:
        os.close(leader)
    return code, shown.decode(errors="replace")


def run_in_log(args: list[str], home: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "monitor", *args], cwd=ROOT, env=_env(home),
                          stdin=subprocess.DEVNULL, capture_output=True, text=True,
                          timeout=300)


def test_model_build_shows_progress_on_a_terminal_and_nothing_in_a_log(tmp_path):
    code, shown = run_on_terminal(["model", "build", "--out", str(tmp_path / "a.onnx")],
                                  tmp_path)
    assert code == 0, shown
    assert "model build" in shown and "building the fp32 model" in shown
    done = run_in_log(["model", "build", "--out", str(tmp_path / "b.onnx")], tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    assert done.stdout.startswith("wrote ") and len(done.stdout.splitlines()) == 1


@pytest.mark.slow
def test_replay_shows_progress_on_a_terminal_and_nothing_in_a_log(tmp_path, synthetic_model):
    video = tmp_path / "scene.mp4"
    write_video(video, DemoScene(duration_s=2.0, fps=10).frames(), 10)
    args = ["replay", str(video), "--model", str(synthetic_model), "--no-video"]
    code, shown = run_on_terminal([*args, "--out", str(tmp_path / "a")], tmp_path)
    assert code == 0, shown
    assert "replay" in shown and "/20" in shown
    done = run_in_log([*args, "--out", str(tmp_path / "b")], tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    assert "outputs:" in done.stdout


@pytest.mark.slow
def test_demo_model_build_shows_progress_on_a_terminal(tmp_path):
    """`monitor demo` builds the model first (no model in the cache yet): that step has a bar
    too, before the scene's. Stopped once the replay's bar shows (the demo's own result is
    tested elsewhere; the whole demo on a loaded machine would take minutes)."""
    code, shown = run_on_terminal(["demo", "--out", str(tmp_path / "demo")], tmp_path / "home",
                                  timeout=300, until="replay")
    assert code is None, shown[-2000:]  # stopped at the replay's bar, not ended before it
    assert "building the synthetic model" in shown
    assert "rendering scene" in shown and "replay" in shown
