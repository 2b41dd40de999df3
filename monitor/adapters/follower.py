"""The adapter's loop: commands in over Zenoh, the consumer rule once, a snapshot per tick out.

``subscribe`` declares what ``monitor watch`` listens to (commands, alerts, liveliness) into a
bounded ``Inbox`` (newest wins under a flood); ``Follower.step`` drains it into the
``CommandWatchdog`` and returns the snapshot of the verdict at that moment; ``Follower.run``
does that every ``tick_s`` and hands the snapshot to every output. An output that raises is
counted and logged, and the others go on: one broken protocol never silences another.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence

import zenoh

from monitor.adapters.snapshot import Output, SafetySnapshot, snapshot_of
from monitor.wire.cell_consumer import CellWatchdog
from monitor.wire.consumer import CommandWatchdog
from monitor.wire.inbox import Inbox

log = logging.getLogger("monitor.adapters")

DEFAULT_TICK_S = 0.02  # 50 Hz: a PLC polling every 10-50 ms sees each change within a tick


def subscribe(session: zenoh.Session, keys, inbox: Inbox,
              clock: Callable[[], float] = time.monotonic) -> list:
    """Commands (with their signature and both arrival clocks), alerts and liveliness of the
    cell's monitors into ``inbox``; the declared entities, for closing."""

    def attachment(s) -> bytes | None:
        return s.attachment.to_bytes() if s.attachment is not None else None

    def put(kind: str, *item) -> None:
        inbox.put(kind, (kind, *item))

    return [
        session.declare_subscriber(keys.command, lambda s: put(
            "command", s.payload.to_bytes(), attachment(s), clock(), time.time())),
        session.declare_subscriber(keys.alert, lambda s: put(
            "alert", s.payload.to_bytes(), attachment(s), clock())),
        session.liveliness().declare_subscriber(keys.alive + "/*", lambda s: put(
            "alive", str(s.key_expr), s.kind == zenoh.SampleKind.PUT, clock()), history=True),
    ]


class Follower:
    """The consumer rule over the inbox; a ``SafetySnapshot`` per ``step``."""

    def __init__(self, dog: CommandWatchdog | CellWatchdog, inbox: Inbox,
                 cameras: Sequence[str] = (),
                 clock: Callable[[], float] = time.monotonic,
                 wall: Callable[[], float] = time.time) -> None:
        self.dog = dog
        self.inbox = inbox
        self.cameras = tuple(cameras)
        self.clock = clock
        self.wall = wall
        self.counter = 0
        self.accepted = 0
        self.received: float | None = None  # arrival of the last accepted command
        self.output_errors: Counter[str] = Counter()
        self.alerts: list[tuple[bytes, float]] = []  # raw alerts since the last step

    def drain(self, timeout: float = 0.0) -> None:
        """Feed what is waiting now (waiting up to ``timeout`` s for the first item). At most
        the entries present at the start: under a flood the Zenoh threads refill the inbox as
        fast as it is read, and an unbounded drain would never hand a snapshot to the outputs
        (nor see a stop signal)."""
        entry = self.inbox.get(timeout=timeout)
        budget = len(self.inbox) + 1
        while entry is not None and budget > 0:
            budget -= 1
            kind, payload, extra, t_recv, *rest = entry
            if kind == "command":
                # both clocks read on arrival: time in the inbox counts against the ttl
                # rest: the wall clock on arrival (and, from subscribe_cell, the key)
                if self.dog.on_command(payload, t_recv, extra, *rest) is None:
                    self.accepted += 1
                    self.received = t_recv
            elif kind == "alive":
                self.dog.on_liveliness(payload, bool(extra))
            elif kind == "alert":
                self.alerts.append((payload, t_recv))
                del self.alerts[:-64]  # bounded: outputs take what they want each step
            entry = self.inbox.get(timeout=0.0) if budget > 0 else None

    def step(self, timeout: float = 0.0) -> SafetySnapshot:
        self.drain(timeout)
        now = self.clock()
        self.counter += 1
        return snapshot_of(self.dog.verdict(now), now, self.wall(), self.counter,
                           self.received, self.cameras)

    def publish(self, outputs: Sequence[Output], snapshot: SafetySnapshot) -> None:
        for out in outputs:
            try:
                out.publish(snapshot)
            except Exception as exc:  # one broken output never silences the others
                self.output_errors[out.name] += 1
                if self.output_errors[out.name] in (1, 10, 100) or \
                        self.output_errors[out.name] % 1000 == 0:
                    log.error("output %s failed (%d times): %s", out.name,
                              self.output_errors[out.name], exc)

    def run(self, outputs: Sequence[Output], stop: threading.Event,
            tick_s: float = DEFAULT_TICK_S, duration: float | None = None) -> None:
        """Step and publish every ``tick_s`` until ``stop`` (or ``duration`` s)."""
        end = None if duration is None else self.clock() + duration
        next_tick = self.clock()
        while not stop.is_set() and (end is None or self.clock() < end):
            next_tick += tick_s
            wait = max(0.0, next_tick - self.clock())
            if wait == 0.0:
                next_tick = self.clock()  # fell behind (frozen, loaded): restart the grid
            self.publish(outputs, self.step(timeout=wait))
