"""One monitor per cell (per role), the bus's side (``monitor.bus.session.SafetyBus``).

At start the bus refuses to run when another monitor's liveliness token is present on the cell
(``refuse_if_another``); later it reports ``duplicate_monitor`` (``faults``) and sends STOP
(``guarded``) while another monitor's token or commands are seen. Only commands signed with this
cell's monitor key count as another monitor's; unsigned or wrongly signed ones are counted and
alerted (``monitor.bus.foreign``).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable

import zenoh
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from monitor.bus.foreign import ForeignCommands
from monitor.errors import ConfigError
from monitor.policy import STOP, Command, Reason
from monitor.types import Alert, Fault

SEEN_S = 2.0  # another monitor's commands count for this long after the last one
MAX_OTHERS = 64  # bound on remembered tokens and boots: a flood cannot grow memory


class DuplicateMonitor(ConfigError):
    """Another monitor is live on this cell."""


class PeerWatch:
    """Other monitors on this cell (liveliness tokens, commands signed with our key) and foreign
    traffic on our command key. Thread-safe."""

    def __init__(self, *, cell: str, role: str, instance: str, alive_key: str,
                 command_key: str, public_key: Ed25519PublicKey | None,
                 clock: Callable[[], float]) -> None:
        self.cell, self.role, self.instance = cell, role, instance
        self.alive_key = alive_key
        self._clock = clock
        self._lock = threading.Lock()
        self._alive: set[str] = set()  # other monitors' liveliness tokens on this cell
        self._seen: dict[str, float] = {}  # other monitors' boots -> last command time
        self._foreign = ForeignCommands(public_key, command_key)

    def where(self) -> str:
        role = f" as {self.role!r}" if self.role else ""
        return f"on cell {self.cell!r}{role}"

    def _per(self) -> str:
        return "role" if self.role else "cell"

    def refuse_if_another(self, session: zenoh.Session, check_s: float) -> None:
        """Refuse to start when a monitor's liveliness token is already present on the cell."""
        if check_s <= 0:
            return
        others: list[str] = []
        deadline = self._clock() + check_s
        # asked again until the window ends: a client whose link to the router is still being
        # set up gets an empty answer at once, and would miss a monitor that is live
        while not others and (left := deadline - self._clock()) > 0:
            asked = self._clock()
            with contextlib.suppress(Exception):
                for reply in session.liveliness().get(self.alive_key + "/*", timeout=left):
                    if reply.ok is not None:
                        others.append(str(reply.ok.key_expr).rsplit("/", 1)[-1])
            if not others and self._clock() - asked < 0.05:
                time.sleep(min(0.1, max(0.0, deadline - self._clock())))
        if others:
            raise DuplicateMonitor(
                f"another monitor ({others[0]}) is already live {self.where()} "
                f"({self.alive_key}/{others[0]}); run one monitor per " + self._per())

    def others(self) -> list[str]:
        """Other monitors seen now: live tokens and boots whose commands came recently."""
        now = self._clock()
        with self._lock:
            seen = {f"boot {b}" for b, t in self._seen.items() if now - t < SEEN_S}
            return sorted(self._alive | seen)

    def faults(self) -> list[Fault]:
        others = self.others()
        if not others:
            return []
        return [Fault("duplicate_monitor", f"another monitor is live {self.where()} "
                      f"({', '.join(others[:3])}); run one per " + self._per(),
                      stop=True, source="bus", latch=True)]

    def guarded(self, command: Command) -> Command:
        """STOP while another monitor is live on the cell: the consumer cannot know whom to
        follow, and neither monitor alone sees what the other sees."""
        others = self.others()
        if not others or (command.state == STOP and any(
                r.code == "duplicate_monitor" for r in command.reasons)):
            return command
        reason = Reason("duplicate_monitor", f"another monitor is live on this cell "
                        f"({', '.join(others[:3])})")
        return Command(STOP, 0.0, (*command.reasons, reason), command.since, command.latched,
                       command.reset)

    def foreign_counts(self) -> dict[str, int]:
        return self._foreign.counts()

    def foreign_alert(self, source: str) -> Alert | None:
        return self._foreign.alert(source, self._clock())

    def on_alive(self, sample: zenoh.Sample) -> None:
        instance = str(sample.key_expr).rsplit("/", 1)[-1]
        if instance == self.instance:
            return
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                if len(self._alive) < MAX_OTHERS:
                    self._alive.add(instance)
            else:
                self._alive.discard(instance)

    def on_command(self, sample: zenoh.Sample, own_boot: str) -> None:
        """Commands on our key from another sender: a second monitor when signed with our key
        (``monitor.bus.foreign``), else counted and alerted."""
        try:
            signature = sample.attachment.to_bytes() if sample.attachment is not None else None
            boot = self._foreign.classify(sample.payload.to_bytes(), signature, own_boot,
                                          self._clock(), time.time())
        except Exception:  # nothing a sender does may kill this callback
            return
        if boot is not None:
            with self._lock:
                if len(self._seen) < MAX_OTHERS or boot in self._seen:
                    self._seen[boot] = self._clock()
