"""The pipeline's zone sets between decisions (docs/cases.md).

``ZoneSets`` holds the selection state a ``Pipeline`` owns: the plan of the zone file's
``sets`` (None without them: every zone applies, the most protection), the state of the
selector (it starts with the default set at the first decision, and the selector's ttl counts
from there) and the sets in force at the newest decision. The switch-over rules themselves are
the pure ``monitor.cases.sets``.
"""

from __future__ import annotations

from collections.abc import Sequence

from monitor.cases import sets as cases
from monitor.types import Fault, ZoneReport
from monitor.zones import Cell


class ZoneSets:
    """Which zone sets apply at each decision, and the filter of the merged zone answer."""

    def __init__(self, cell: Cell | None) -> None:
        self.plan = cases.plan_of(cell.spec) if cell is not None else None
        self.state: cases.CaseState | None = None
        self.in_force: cases.ZonesInForce | None = None

    def take_events(self, events: Sequence[cases.Selection | cases.Refusal],
                    now: float) -> None:
        """Selections (verified) and refused requests received since the last decision; the
        next decision uses them. Without sets in the zone file they are ignored."""
        if self.plan is None:
            return
        state = self.state or cases.initial_case(self.plan, now)
        self.state = cases.apply_events(self.plan, state, events, now)

    def filter(self, report: ZoneReport | None, now: float,
               faults: list[Fault]) -> ZoneReport | None:
        """The merged answer with only the zones of the sets applying at ``now``; the
        selection's faults added to ``faults``."""
        if self.plan is None:
            return report
        state = self.state or cases.initial_case(self.plan, now)
        self.state = cases.advance(self.plan, state, now)
        self.in_force = cases.in_force(self.plan, self.state, now)
        faults.extend(self.in_force.faults)
        return cases.filter_report(report, self.in_force)

    def restart(self, cell: Cell) -> None:
        """A zone apply: the sets of the new file, starting again from its default."""
        self.plan = cases.plan_of(cell.spec)
        self.state = None
        self.in_force = None
