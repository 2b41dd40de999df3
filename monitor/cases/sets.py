"""The pure logic of zone sets: which sets apply at a time, and the faults of the selection.

A *selection* names the set the robot program works in now. A switch from set A to set B
takes effect only after ``switch_over_s``: until then both A and B apply (the union: never
less protection while switching). A verified selection of an unknown set or of a transition the
zone file does not allow, and a selector that has said nothing for ``selector_ttl_s`` are STOP
faults with the reason; the sets in force stay as they were. Such a fault holds until the next
valid selection. A refused request (unsigned, wrongly signed, replayed, stale) comes from no
selector: it changes nothing (the sender has the refusal as its answer). Zones that no set
names apply always.

No clocks, no I/O: ``apply_event`` and ``advance`` take the time they are given
(``Pipeline``'s ``now``), so replay and tests are deterministic.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace

from monitor.types import Fault, ZoneHit, ZoneReport

SOURCE = "case"  # Fault.source of every selection fault


@dataclass(frozen=True)
class ZoneSet:
    id: str
    zones: frozenset[str]
    speed_scale: float | None = None  # caps the set's warning zones while it applies


@dataclass(frozen=True)
class CasePlan:
    """The zone file's sets and switching rules (``plan_of(cell_spec)``)."""

    sets: tuple[ZoneSet, ...]
    default: str
    transitions: frozenset[tuple[str, str]] | None = None  # None: any change allowed
    switch_over_s: float = 1.0
    selector_ttl_s: float | None = None  # None: silence is not watched

    def get(self, set_id: str) -> ZoneSet | None:
        return next((s for s in self.sets if s.id == set_id), None)

    @property
    def switched_zones(self) -> frozenset[str]:
        """Zones some set names: they apply only while such a set applies."""
        return frozenset().union(*(s.zones for s in self.sets))

    def allowed(self, old: str, new: str) -> bool:
        return old == new or self.transitions is None or (old, new) in self.transitions


def plan_of(spec) -> CasePlan | None:
    """The plan of a validated zone file spec (``CellSpec``), None when it declares no sets."""
    if not spec.sets:
        return None
    return CasePlan(
        sets=tuple(ZoneSet(s.id, frozenset(s.zones), s.speed_scale) for s in spec.sets),
        default=spec.default_set,
        transitions=(frozenset(tuple(p) for p in spec.transitions)
                     if spec.transitions is not None else None),
        switch_over_s=spec.switch_over_s, selector_ttl_s=spec.selector_ttl_s)


@dataclass(frozen=True)
class Selection:
    """A verified request: the selector names ``set_id`` (at ``seq``); ``age_s``: how far its
    signed wall time lay behind the monitor's clock when it arrived (0 when ahead)."""

    set_id: str
    selector: str = ""
    seq: int = 0
    age_s: float = field(default=0.0, compare=False)  # how it arrived, not what it says


@dataclass(frozen=True)
class Refusal:
    """A request that was refused before it could select anything (unsigned, wrongly signed,
    replayed, stale, malformed): the reason told to the sender. It changes no state."""

    reason: str
    selector: str = ""


@dataclass(frozen=True)
class CaseState:
    """What the switch remembers: the set selected last, the sets that apply now (several
    while switching), when the switch-over ends, when the selector last spoke, and the fault
    of the last bad selection (held until a valid one)."""

    selected: str
    applied: tuple[str, ...]
    switch_until: float | None = None
    heard: float = 0.0
    fault: Fault | None = None


def initial_case(plan: CasePlan, now: float) -> CaseState:
    """The default set at start; the selector's ttl counts from here."""
    return CaseState(plan.default, (plan.default,), None, now)


def advance(plan: CasePlan, state: CaseState, now: float) -> CaseState:
    """The state at ``now``: a switch-over that has run its time leaves only the new set."""
    if state.switch_until is not None and now >= state.switch_until:
        return replace(state, applied=(state.selected,), switch_until=None)
    return state


def apply_event(plan: CasePlan, state: CaseState, event: Selection | Refusal,
                now: float) -> CaseState:
    """One request at ``now``: a valid selection of the set selected now is a heartbeat; of an
    allowed other set starts a switch-over (every set applying now keeps applying until it
    ends); a verified selection of an unknown set or a disallowed change is a fault and
    changes no set; a refused request changes nothing."""
    state = advance(plan, state, now)
    if isinstance(event, Refusal):
        # unsigned, forged, replayed, stale: it came from no selector, so it says nothing
        # about the robot and changes nothing (a STOP here was a one-packet denial of
        # service that latched the cell); the sender had the refusal as its answer
        return state
    if plan.get(event.set_id) is None:
        known = ", ".join(s.id for s in plan.sets)
        return replace(state, fault=Fault("case_unknown", f"{event.selector or 'selector'} "
                                          f"selected unknown zone set {event.set_id!r} (sets: "
                                          f"{known}); {state.selected!r} stays", True, SOURCE))
    if not plan.allowed(state.selected, event.set_id):
        return replace(state, fault=Fault(
            "case_disallowed", f"{event.selector or 'selector'} selected zone set "
            f"{event.set_id!r} from {state.selected!r}: not an allowed transition; "
            f"{state.selected!r} stays", True, SOURCE))
    # heard as of when the selector *sent* it: selections held back on the path (signed, in
    # sequence, inside the window) are as silent as their age says, never a fresh heartbeat
    heard = max(state.heard, now - max(0.0, event.age_s))
    if event.set_id == state.selected:
        return replace(state, heard=heard, fault=None)
    applied = tuple(dict.fromkeys((*state.applied, event.set_id)))
    until = now + plan.switch_over_s
    if plan.switch_over_s <= 0.0:
        applied, until = (event.set_id,), None
    return CaseState(event.set_id, applied, until, heard, None)


@dataclass(frozen=True)
class ZonesInForce:
    """The sets applying now and what that means for zone hits."""

    sets: tuple[str, ...]
    dropped: frozenset[str]  # zones of sets that do not apply now: their hits do not count
    scales: tuple[tuple[str, float], ...] = ()  # zone -> speed cap from its applying sets
    faults: tuple[Fault, ...] = ()
    switching: bool = False

    @property
    def label(self) -> str:
        return "+".join(self.sets)


def in_force(plan: CasePlan, state: CaseState, now: float) -> ZonesInForce:
    """The zones in force at ``now`` (``state`` advanced to ``now`` first) and the faults:
    the held fault of a bad selection, and silence longer than ``selector_ttl_s``."""
    state = advance(plan, state, now)
    applying = [s for s in plan.sets if s.id in state.applied]
    active = frozenset().union(*(s.zones for s in applying))
    scales: dict[str, float] = {}
    for s in applying:
        if s.speed_scale is None:
            continue
        for zid in s.zones:
            # in several applying sets: the slowest cap (never less protection)
            scales[zid] = min(scales.get(zid, 1.0), s.speed_scale)
    faults = [state.fault] if state.fault is not None else []
    ttl = plan.selector_ttl_s
    if ttl is not None and now - state.heard > ttl:
        faults.append(Fault("case_selector_silent", f"no zone set selection for "
                            f"{now - state.heard:.1f} s (> selector_ttl_s {ttl:g} s); "
                            f"{state.selected!r} stays", True, SOURCE))
    return ZonesInForce(state.applied, plan.switched_zones - active,
                        tuple(sorted(scales.items())), tuple(faults),
                        state.switch_until is not None)


def filter_report(report: ZoneReport | None, zones: ZonesInForce) -> ZoneReport | None:
    """``report`` with the hits of zones that do not apply now left out and the warning hits
    of capped zones slowed to the cap. Pure; the unfiltered answer stays with the caller (a
    later switch judges the same frame anew)."""
    if report is None:
        return None
    scales = dict(zones.scales)
    if not zones.dropped and not scales:
        return report
    hits = tuple(_capped(h, scales) for h in report.hits if h.zone_id not in zones.dropped)
    return replace(report, hits=hits)


def _capped(hit: ZoneHit, scales: dict[str, float]) -> ZoneHit:
    cap = scales.get(hit.zone_id)
    if cap is None or hit.kind != "warning" or hit.speed_scale <= cap:
        return hit
    return replace(hit, speed_scale=cap)


def apply_events(plan: CasePlan, state: CaseState, events: Iterable[Selection | Refusal],
                 now: float) -> CaseState:
    for event in events:
        state = apply_event(plan, state, event, now)
    return state
