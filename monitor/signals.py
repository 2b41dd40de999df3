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
    """SIGINT/SIGTERM handling for a long-running command (main thread only).

    As a context manager ``__enter__`` returns the stop event; ``install()`` / ``restore()``
    do the same for callers that hold the object (``monitor run``, ``replay``, ``demo``).
    ``on_force(action)`` registers a last action (e.g. publish STOP) that runs, each bounded by
    ``force_timeout_s``, before a forced exit (the grace deadline or a second signal).
    """

    def __init__(self, grace_s: float = 1.5, hard_s: float = 1.9, name: str = "monitor",
                 stop: threading.Event | None = None, force_timeout_s: float = 0.15) -> None:
        if not 0 < grace_s < hard_s:
            raise ValueError("need 0 < grace_s < hard_s")
        self.grace_s = grace_s
        self.hard_s = hard_s
        self.name = name
        self.force_timeout_s = force_timeout_s
        self.stop = stop or threading.Event()
        self.signum: int | None = None
        self._old: dict = {}
        self._timer: threading.Timer | None = None
        self._forces: list[Callable[[], None]] = []

    @property
    def received(self) -> int | None:
        """The first signal received (None before any)."""
        return self.signum

    @property
    def exit_code(self) -> int:
        """128 + the signal number once signalled (the shell's convention), else 0."""
        return 128 + self.signum if self.signum else 0

    def install(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for s in SIGNALS:
                self._old[s] = signal.signal(s, self._on_signal)
        return self

    def restore(self) -> None:
        if self._timer is not None:
            self._timer.cancel()  # wound down in time; the kernel timer stays armed until exit
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old.clear()

    def __enter__(self) -> threading.Event:
        if threading.current_thread() is not threading.main_thread():
            raise RuntimeError("StopSignals must be entered in the main thread")
        self.install()
        return self.stop

    def __exit__(self, *exc) -> None:
        self.restore()

    def on_force(self, action: Callable[[], None]) -> Callable[[], None]:
        """Register a last action for a forced exit; returns a function that removes it."""
        self._forces.append(action)
        return lambda: self._forces.remove(action) if action in self._forces else None

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

    def exit_now(self, code: int) -> None:
        """Leave without the interpreter's teardown (joins of library threads, finalisers):
        after a signal everything of ours is closed, and a loaded machine can spend seconds in
        that teardown. Output written so far is flushed first."""
        import logging

        _flush()
        logging.shutdown()
        os._exit(code)

    def _exit(self, message: str, code: int) -> None:
        for action in list(self._forces):  # e.g. the final STOP, best effort and bounded
            worker = threading.Thread(target=_quietly, args=(action,), daemon=True)
            worker.start()
            worker.join(self.force_timeout_s)
        with contextlib.suppress(Exception):
            print(message, file=sys.stderr)
        _flush()
        os._exit(code)


def _quietly(action: Callable[[], None]) -> None:
    with contextlib.suppress(Exception):  # best effort on the way out; nothing left to tell
        action()


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
