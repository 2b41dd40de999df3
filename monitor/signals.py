"""Stop on SIGINT/SIGTERM within a bounded time, whatever the process is doing.

A Python signal handler only runs when the main thread gets back to the interpreter; while it
sits in a blocking Rust call (``zenoh.open``, ``Session.get``, ``Session.close``) the signal
waits, possibly forever (issue 13: ``timeout 6 monitor watch`` hung for an hour in a futex).
Masking the signals and taking them in a thread does not work either: numpy and OpenCV start
threads at import that would still receive them. So:

* the main thread never blocks in Zenoh: ``call_interruptible`` runs such calls in a helper
  thread while the main thread waits in short slices (handlers run between them);
* first signal: set the ``stop`` event (the command winds down: closes its session, prints its
  summary) and arm a deadline: after ``grace_s`` the process flushes and ``os._exit``s; a kernel
  timer (SIGALRM, default action: terminate) backs that up at ``hard_s`` even if no Python code
  can run any more (a hang in interpreter shutdown);
* second signal: flush and ``os._exit`` at once.

Use it first thing in a command::

    with StopSignals() as stop:
        session = call_interruptible(lambda: open_session(cfg), stop)
        ...
        stop.wait()

``close_bounded(session)`` closes a Zenoh session in a helper thread with a deadline (after
undeclaring Python-callback entities, which otherwise keep the close waiting).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable
from typing import TypeVar

SIGNALS = (signal.SIGINT, signal.SIGTERM)
T = TypeVar("T")


class Interrupted(Exception):
    """A stop signal arrived while waiting for a blocking call."""


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()


class StopSignals:
    """Context manager; ``__enter__`` returns the stop event. Main thread only; the previous
    handlers are restored on exit."""

    def __init__(self, grace_s: float = 1.5, hard_s: float = 1.9, name: str = "monitor") -> None:
        if not 0 < grace_s < hard_s:
            raise ValueError("need 0 < grace_s < hard_s")
        self.grace_s = grace_s
        self.hard_s = hard_s
        self.name = name
        self.stop = threading.Event()
        self.signum: int | None = None
        self._old: dict = {}
        self._timer: threading.Timer | None = None

    @property
    def exit_code(self) -> int:
        """128 + the signal number once signalled (the shell's convention), else 0."""
        return 128 + self.signum if self.signum else 0

    def __enter__(self) -> threading.Event:
        if threading.current_thread() is not threading.main_thread():
            raise RuntimeError("StopSignals must be entered in the main thread")
        for s in SIGNALS:
            self._old[s] = signal.signal(s, self._on_signal)
        return self.stop

    def __exit__(self, *exc) -> None:
        if self._timer is not None:
            self._timer.cancel()  # wound down in time; the kernel timer stays armed until exit
        for s, h in self._old.items():
            signal.signal(s, h)

    def _on_signal(self, signum: int, frame) -> None:
        if self.signum is not None:  # the second signal: no more waiting
            self._exit(f"{self.name}: second signal; exiting now", 128 + signum)
        self.signum = signum
        self.stop.set()
        # backstop that needs no Python: SIGALRM's default action terminates the process
        signal.setitimer(signal.ITIMER_REAL, self.hard_s)
        self._timer = threading.Timer(self.grace_s, self._exit, args=(
            f"{self.name}: did not stop within {self.grace_s:g} s; exiting anyway",
            128 + signum))
        self._timer.daemon = True
        self._timer.start()

    @staticmethod
    def _exit(message: str, code: int) -> None:
        with contextlib.suppress(Exception):
            print(message, file=sys.stderr)
        _flush()
        os._exit(code)


def exit_if_stopped(stop: threading.Event, code: int = 0) -> int:
    """After a stop signal, once the command has closed its session and printed its summary:
    flush and ``os._exit(code)`` instead of returning into interpreter shutdown, where Zenoh's
    runtime teardown takes a second or more (and may hang). Returns ``code`` otherwise."""
    if stop.is_set():
        _flush()
        os._exit(code)
    return code


def wait_for_stop(stop: threading.Event, slice_s: float = 0.05) -> None:
    """Block until ``stop`` is set, in slices: a signal delivered to another thread (numpy's,
    Zenoh's) only runs its Python handler when the main thread wakes up."""
    while not stop.wait(slice_s):
        pass


def call_interruptible(fn: Callable[[], T], stop: threading.Event, slice_s: float = 0.05) -> T:
    """``fn()`` in a helper thread; the caller waits in slices so signal handlers run. Raises
    Interrupted when ``stop`` is set first (the call is left behind in its daemon thread), and
    re-raises what ``fn`` raised."""
    done = threading.Event()
    box: dict = {}

    def run() -> None:
        try:
            box["value"] = fn()
        except BaseException as exc:  # handed to the caller
            box["error"] = exc
        done.set()

    threading.Thread(target=run, name="blocking-call", daemon=True).start()
    while not done.wait(slice_s):
        if stop.is_set():
            raise Interrupted
    if "error" in box:
        raise box["error"]
    return box["value"]


def disarm_hard_deadline() -> None:
    """Cancel the SIGALRM backstop (for in-process callers that keep running, e.g. tests)."""
    signal.setitimer(signal.ITIMER_REAL, 0)


def close_bounded(session, timeout: float = 1.0, undeclare: Iterable = ()) -> bool:
    """Undeclare ``undeclare`` (subscribers, queryables, tokens), then close ``session`` in a
    daemon thread; True when the close finished within ``timeout`` seconds. A close that does
    not finish is left behind (the caller logs and exits anyway)."""
    for entity in undeclare:
        if entity is not None:
            with contextlib.suppress(Exception):
                entity.undeclare()
    done = threading.Event()

    def close() -> None:
        with contextlib.suppress(Exception):
            session.close()
        done.set()

    threading.Thread(target=close, name="zenoh-close", daemon=True).start()
    deadline = time.monotonic() + timeout
    while not done.wait(0.05):  # in slices: a second signal's handler runs in between
        if time.monotonic() > deadline:
            return False
    return True
