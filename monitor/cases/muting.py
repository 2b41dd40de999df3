"""Bounded muting of named zones (docs/muting.md): the rules of the zone file and the pure
``Mutes`` state.

A zone may be muted only when its zone file entry says ``mute:`` (operators allowed, maximum
duration, what it is while muted) and not ``unmutable: true``; a protective zone without
``mute:`` is unmutable. A request (already verified by the bus: signature, cell, boot, clock
window, replay) names a zone, an operator and a duration; ``Mutes.request`` accepts it or
refuses it with a reason. An accepted mute holds from the step that accepted it for exactly
its duration: ``active(now)`` holds it while ``now < end`` and never at ``end`` or after.

Pure: no clock, no I/O; every answer is a new ``Mutes`` and the outcome. The pipeline holds
the current one, applies ``muted_zones(now)`` to the merged zone report at each decision
(``monitor.zones.check.apply_mutes``) and turns starts and ends into alerts.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace

# the SLOW scale of a muted zone checked as a warning zone, when neither the mute nor the zone
# file's warning zones give one: slow enough to matter (docs/muting.md)
DEFAULT_MUTED_SCALE = 0.1
SEEN_IDS = 1000  # request ids remembered against replay (the bus also checks a clock window)


@dataclass(frozen=True)
class MuteRule:
    """What the zone file allows for one zone. ``as_`` is ``warning`` or ``none``; ``scale``
    the SLOW scale while muted as a warning zone. ``mutable`` False: every mute is refused
    (``why`` says why)."""

    zone_id: str
    kind: str
    mutable: bool
    why: str = ""
    max_s: float = 0.0
    operators: tuple[str, ...] = ()
    as_: str = "warning"
    scale: float = DEFAULT_MUTED_SCALE


def mute_faults(zone) -> Iterable[str]:
    """Zone-file errors of one zone's muting fields (``monitor.zones.validate``)."""
    mute = getattr(zone, "mute", None)
    if mute is None:
        return
    if zone.kind not in ("protective", "warning"):
        yield f"mute: only protective and warning zones can be muted, not {zone.kind}"
    if getattr(zone, "unmutable", None):
        yield "mute: the zone also says unmutable: true; say one of them"
    if zone.kind == "warning" and mute.as_ == "warning":
        yield "mute: a warning zone muted as a warning zone changes nothing; say as: none"
    names = [o.strip() for o in mute.operators]
    if any(not o for o in names):
        yield "mute: operators: an empty operator name"
    if len(set(names)) != len(names):
        yield "mute: operators: an operator is listed twice"


def mute_rules(cell) -> dict[str, MuteRule]:
    """Zone id -> its muting rule, for every enabled protective and warning zone of ``cell``
    (a ``monitor.zones.Cell``; None: no zones, nothing can be muted)."""
    if cell is None:
        return {}
    zones = [z for z in cell.zones if z.kind in ("protective", "warning") and z.enabled]
    scales = [z.speed_scale for z in zones if z.kind == "warning" and z.speed_scale is not None]
    slowest = min(scales) if scales else DEFAULT_MUTED_SCALE
    out: dict[str, MuteRule] = {}
    for z in zones:
        mute = getattr(z, "mute", None)
        if getattr(z, "unmutable", None):
            out[z.id] = MuteRule(z.id, z.kind, False, "it is marked unmutable")
        elif mute is None:
            default = " (protective zones are unmutable unless they say mute:)" \
                if z.kind == "protective" else ""
            out[z.id] = MuteRule(z.id, z.kind, False,
                                 f"its zone file entry has no mute: section{default}")
        else:
            scale = mute.speed_scale if mute.speed_scale is not None else slowest
            out[z.id] = MuteRule(z.id, z.kind, True, max_s=float(mute.max_s),
                                 operators=tuple(o.strip() for o in mute.operators),
                                 as_=mute.as_, scale=float(scale))
    return out


@dataclass(frozen=True)
class MuteRequest:
    """A verified request (``monitor.cases.mute_requests``): mute ``zone`` for ``duration_s``, or
    end its mute early (``end``). ``time``: when it arrived (the monitor's clock)."""

    zone: str
    operator: str
    duration_s: float
    request_id: str
    time: float
    end: bool = False
    wall: float | None = None  # the sender's wall time (for the audit)


@dataclass(frozen=True)
class Mute:
    """An accepted mute: ``zone`` muted by ``operator`` from ``start`` until ``end`` (the
    policy's clock; ``end`` excluded)."""

    zone: str
    operator: str
    start: float
    end: float
    max_s: float
    as_: str
    scale: float
    request_id: str

    def holds(self, now: float) -> bool:
        return self.start <= now < self.end  # NaN: False (not muted: the safe side)


@dataclass(frozen=True)
class MuteOutcome:
    """What became of one request: accepted or refused with the reason (``mute``: the mute
    it started, or the one it ended)."""

    request: MuteRequest
    accepted: bool
    reason: str
    mute: Mute | None = None


@dataclass(frozen=True)
class Mutes:
    """The mutes of a cell: rules from the zone file, the active mutes, the request ids seen."""

    rules: Mapping[str, MuteRule]
    active: tuple[Mute, ...] = ()
    seen: tuple[str, ...] = ()  # request ids judged, newest last (the last SEEN_IDS)

    @classmethod
    def of(cls, cell) -> Mutes:
        return cls(mute_rules(cell))

    def holding(self, now: float) -> tuple[Mute, ...]:
        """The mutes that hold at ``now``."""
        return tuple(m for m in self.active if m.holds(now))

    def muted_zones(self, now: float) -> dict[str, float | None]:
        """Zone id -> SLOW scale while muted as a warning zone, or None (not checked), at
        ``now``: what ``apply_mutes`` takes."""
        return {m.zone: (m.scale if m.as_ == "warning" else None) for m in self.holding(now)}

    def expire(self, now: float) -> tuple[Mutes, tuple[Mute, ...]]:
        """Drop the mutes that no longer hold at ``now``; the new state and the ended ones."""
        ended = tuple(m for m in self.active if not m.holds(now))
        if not ended:
            return self, ()
        return replace(self, active=tuple(m for m in self.active if m.holds(now))), ended

    def request(self, req: MuteRequest, now: float) -> tuple[Mutes, MuteOutcome]:
        """Judge one request at ``now``: the new state and the outcome."""
        state, _ = self.expire(now)

        def refuse(why: str) -> tuple[Mutes, MuteOutcome]:
            return state, MuteOutcome(req, False, why)

        if req.request_id in state.seen:
            return refuse(f"request id {req.request_id!r} was already used (replayed)")
        state = replace(state, seen=(*state.seen, req.request_id)[-SEEN_IDS:])
        if not math.isfinite(now):
            return refuse("the monitor's clock is not finite")
        rule = state.rules.get(req.zone)
        if rule is None:
            known = ", ".join(sorted(state.rules)) or "none"
            return refuse(f"no enabled protective or warning zone {req.zone!r} (zones: {known})")
        current = next((m for m in state.active if m.zone == req.zone), None)
        if req.end:
            if current is None:
                return refuse(f"zone {req.zone} is not muted")
            ended = replace(current, end=now)
            state = replace(state, active=tuple(m for m in state.active if m is not current))
            return state, MuteOutcome(req, True, f"mute of zone {req.zone} by "
                                      f"{current.operator} ended early by {req.operator}",
                                      ended)
        if not rule.mutable:
            return refuse(f"zone {req.zone} cannot be muted: {rule.why}")
        if req.operator not in rule.operators:
            return refuse(f"operator {req.operator!r} is not allowed to mute zone {req.zone} "
                          f"(allowed: {', '.join(rule.operators)})")
        d = req.duration_s
        if not (math.isfinite(d) and d > 0):
            return refuse(f"mute duration {d!r} s is not a positive number of seconds")
        if d > rule.max_s:
            return refuse(f"mute of {d:g} s is longer than zone {req.zone}'s maximum "
                          f"({rule.max_s:g} s)")
        if current is not None:
            return refuse(f"zone {req.zone} is already muted by {current.operator}; end that "
                          "mute first (a mute is never extended)")
        mute = Mute(req.zone, req.operator, now, now + d, rule.max_s, rule.as_, rule.scale,
                    req.request_id)
        state = replace(state, active=(*state.active, mute))
        what = (f"checked as a warning zone (SLOW x{rule.scale:.2f})" if rule.as_ == "warning"
                else "not checked")
        return state, MuteOutcome(req, True, f"zone {req.zone} muted by {req.operator} for "
                                  f"{d:g} s: {what}", mute)
