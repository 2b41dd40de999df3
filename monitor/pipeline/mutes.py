"""The pipeline's operator mutes between decisions (docs/muting.md).

``MuteDesk`` holds the mute state a ``Pipeline`` owns: requests judged as they come in, mutes
ended at the first decision at or after their end (or all of them after a zone apply), and the
outcomes and alerts that ride on the next ``StepResult``. The rules themselves are the pure
``monitor.cases.muting.Mutes``; this only keeps them between steps and says what changed.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace

from monitor.cases.muting import Mute, MuteOutcome, MuteRequest, Mutes
from monitor.policy.model import Reason
from monitor.timetext import TimeText, seconds
from monitor.types import Alert
from monitor.zones import Cell

log = logging.getLogger("monitor.pipeline")  # the pipeline's log, as before the split


def mute_text(mute: Mute, when: TimeText = seconds) -> str:
    """E.g. ``zone robot-protective muted by anna until 14:03:12 (60 s, 120 s max): checked
    as a warning zone (SLOW x0.30)``."""
    what = (f"checked as a warning zone (SLOW x{mute.scale:.2f})" if mute.as_ == "warning"
            else "not checked")
    return (f"zone {mute.zone} muted by {mute.operator} until {when(mute.end)} "
            f"({mute.end - mute.start:g} s, {mute.max_s:g} s max): {what}")


class MuteDesk:
    """Zones muted by operators (``request``); applied at each decision (``muted``)."""

    def __init__(self, cell: Cell | None) -> None:
        self.mutes = Mutes.of(cell)
        self.when: TimeText = seconds  # times in mute reasons (live: the wall clock)
        self._outcomes: list[MuteOutcome] = []
        self._alerts: list[Alert] = []
        # set by a zone swap: every mute ends at the next decision, which starts from the
        # new cell's mute rules
        self._end_why = ""
        self._next_cell: Cell | None = cell

    def request(self, requests: Sequence[MuteRequest], now: float
                ) -> tuple[MuteOutcome, ...]:
        """Judge mute requests at ``now``: accepted ones hold from ``now`` for their duration.
        The outcomes and their alerts are kept for ``take_events``."""
        from monitor.wire.alerts import mute_alert

        out = []
        for req in requests:
            self.mutes, outcome = self.mutes.request(req, now)
            out.append(outcome)
            log.warning("mute of zone %s by %s %s: %s", req.zone, req.operator,
                        "accepted" if outcome.accepted else "refused", outcome.reason)
            self._alerts.append(mute_alert(outcome, now, self.when))
        self._outcomes.extend(out)
        return tuple(out)

    def end_all(self, cell: Cell, why: str) -> None:
        """A zone apply: every mute ends at the next decision (its zone is protective again;
        re-mute under the new rules of ``cell``)."""
        self._end_why = why
        self._next_cell = cell

    def muted(self, now: float) -> tuple[dict[str, float | None], tuple[Reason, ...]]:
        """The zones muted at ``now`` (for ``apply_mutes``) and the policy's notes; a mute
        that ended is alerted here, at the first decision at or after its end."""
        from monitor.wire.alerts import unmute_alert

        if self._end_why:  # a zone apply ends every mute (the rules may have changed)
            for mute in self.mutes.active:
                log.warning("mute of zone %s by %s ended: %s", mute.zone, mute.operator,
                            self._end_why)
                self._alerts.append(unmute_alert(mute, now, self.when, self._end_why))
            self.mutes = replace(Mutes.of(self._next_cell), seen=self.mutes.seen)
            self._end_why = ""
        self.mutes, ended = self.mutes.expire(now)
        for mute in ended:
            log.warning("mute of zone %s by %s ended", mute.zone, mute.operator)
            self._alerts.append(unmute_alert(mute, now, self.when, "expired"))
        holding = self.mutes.holding(now)
        notes = tuple(Reason("muted", mute_text(m, self.when), zone_id=m.zone,
                             source=m.operator, since=None) for m in holding)
        return self.mutes.muted_zones(now), notes

    def take_events(self) -> tuple[tuple[MuteOutcome, ...], tuple[Alert, ...]]:
        """The outcomes and alerts since the last call (for the next ``StepResult``)."""
        outcomes, alerts = tuple(self._outcomes), tuple(self._alerts)
        self._outcomes.clear()
        self._alerts.clear()
        return outcomes, alerts

    def holding(self, now: float) -> tuple[Mute, ...]:
        """The mutes that hold at ``now``."""
        return self.mutes.holding(now)
