"""Which steps are incidents: pure rules over consecutive step results.

A step opens an incident when the command enters STOP for a cause (not start-up), becomes
latched, answers a reset (accepted or refused), a STOP fault starts, or an alert is raised.
All causes of one step make one incident.
"""

from __future__ import annotations

from dataclasses import dataclass, field

BOOKKEEPING = frozenset({"startup", "clearing", "latched", "shutdown"})


def stop_causes(command) -> set[str]:
    return {r.code for r in command.reasons} - BOOKKEEPING


@dataclass
class Triggers:
    """Remembers the previous step; ``update(result)`` gives this step's causes."""

    stopped_for_cause: bool = False
    latched: bool = False
    # a STOP fault's last sighting: with several cameras a step may carry only its camera's
    # faults, so a fault is new only when unseen for ``fault_gap_s``
    faults: dict[tuple[str, str], float] = field(default_factory=dict)
    fault_gap_s: float = 2.0

    def update(self, result) -> tuple[str, ...]:
        cmd = result.command
        causes: list[str] = []
        # latched with the cause gone, the command names no cause (the latch says it as a past
        # event): still the same STOP for a cause, so a person coming back opens no new one
        for_cause = cmd.state == "STOP" and (bool(stop_causes(cmd))
                                             or (cmd.latched and self.stopped_for_cause))
        if for_cause and not self.stopped_for_cause:
            causes.append("stop")
        self.stopped_for_cause = for_cause
        if cmd.latched and not self.latched:
            causes.append("latch")
        self.latched = bool(cmd.latched)
        if cmd.reset is not None:
            causes.append("reset_accepted" if cmd.reset.accepted else "reset_refused")
        new = False
        for key in {(f.name, f.source) for f in result.faults if f.stop}:
            seen = self.faults.get(key)
            new = new or seen is None or result.now - seen > self.fault_gap_s
            self.faults[key] = result.now
        if new:
            causes.append("fault")
        if result.alerts:
            causes.append("alert")
        return tuple(causes)
