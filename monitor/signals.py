"""Stop on SIGINT/SIGTERM within a bounded time, whatever the process is doing.

Why not ``signal.signal``: a Python handler only runs when the main thread gets back to the
interpreter. While it sits in a blocking Rust call (``zenoh.open``, ``Session.close``, a
finaliser joining Zenoh threads) the signal waits, possibly forever (issue 13: ``timeout 6
monitor watch`` hung for an hour in a futex). So ``StopSignals`` blocks SIGINT/SIGTERM in the
calling thread -- and thereby in every thread started later, Zenoh's included -- and a small
thread takes them with ``sigtimedwait``:

* first signal: set the ``stop`` event (the command winds down: closes its session, prints its
  summary) and arm a deadline: after ``grace_s`` the process flushes and ``os._exit``s; a kernel
  timer (SIGALRM, default action: terminate) backs that up at ``hard_s`` even if no Python code
  can run any more;
* second signal: flush and ``os._exit`` at once.

Use it first thing in a command, before any Zenoh session exists::

    with StopSignals() as stop:
        with open_session(cfg) as session:
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
from collections.abc import Iterable

SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()


class StopSignals:
    """Context manager; ``__enter__`` returns the stop event. Main thread only."""

    def __init__(self, grace_s: float = 1.5, hard_s: float = 1.9, name: str = "monitor") -> None:
        if not 0 < grace_s < hard_s:
            raise ValueError("need 0 < grace_s < hard_s")
        self.grace_s = grace_s
        self.hard_s = hard_s
        self.name = name
        self.stop = threading.Event()
        self.signum: int | None = None
        self._done = threading.Event()
        self._thread: threading.Thread | None = None
        self._old_mask: set | None = None
        self._timer: threading.Timer | None = None

    @property
    def exit_code(self) -> int:
        """128 + the signal number once signalled (the shell's convention), else 0."""
        return 128 + self.signum if self.signum else 0

    def __enter__(self) -> threading.Event:
        if threading.current_thread() is not threading.main_thread():
            raise RuntimeError("StopSignals must be entered in the main thread")
        self._old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
        self._thread = threading.Thread(target=self._wait_signals, name="stop-signals",
                                        daemon=True)
        self._thread.start()
        return self.stop

    def __exit__(self, *exc) -> None:
        self._done.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._timer is not None:
            self._timer.cancel()  # wound down in time; the kernel timer stays armed until exit
        if self._old_mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, self._old_mask)

    def _wait_signals(self) -> None:
        while not self._done.is_set():
            info = signal.sigtimedwait(SIGNALS, 0.1)
            if info is None:
                continue
            if self.signum is not None:  # the second signal: no more waiting
                self._exit(f"{self.name}: second signal; exiting now", 128 + info.si_signo)
            self.signum = info.si_signo
            self.stop.set()
            # backstop that needs no Python: SIGALRM's default action terminates the process
            signal.setitimer(signal.ITIMER_REAL, self.hard_s)
            self._timer = threading.Timer(self.grace_s, self._exit, args=(
                f"{self.name}: did not stop within {self.grace_s:g} s; exiting anyway",
                128 + info.si_signo))
            self._timer.daemon = True
            self._timer.start()

    @staticmethod
    def _exit(message: str, code: int) -> None:
        with contextlib.suppress(Exception):
            print(message, file=sys.stderr)
        _flush()
        os._exit(code)


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
    return done.wait(timeout)
