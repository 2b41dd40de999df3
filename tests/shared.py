"""Heavy fixtures built once per test run, not once per xdist worker.

Why: the suite runs on three workers that steal tests from each other, so a session or module
fixture used by tests on several workers (a replay of the demo scene, a recorded incident, a
model's envelope) is otherwise built twice, each build taking 10-60 s of a core on a 2-core
host. The first worker to ask builds it under a file lock in the run's shared temp folder
(the pattern pytest-xdist documents); the others wait for the lock and reads the result.
A build that raises leaves nothing behind, so the next asker builds again and fails the same
way in its own tests.
"""

from __future__ import annotations

import fcntl
import os
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest

T = TypeVar("T")


def run_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The temp folder every worker of this run shares (the worker's own one without xdist)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def built_once(tmp_path_factory: pytest.TempPathFactory, name: str,
               build: Callable[[Path], T]) -> T:
    """``build(folder)`` once per run: its files go in ``folder`` (shared by the workers) and
    its return value must pickle (paths, dataclasses, arrays)."""
    root = run_root(tmp_path_factory)
    folder = root / f"built-{name}"
    result = folder / "result.pickle"
    with open(root / f"built-{name}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if result.is_file():
                return pickle.loads(result.read_bytes())
            folder.mkdir(exist_ok=True)
            value = build(folder)
            partial = result.with_suffix(".partial")
            partial.write_bytes(pickle.dumps(value))
            partial.replace(result)  # never a half-written result for another worker
            return value
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
