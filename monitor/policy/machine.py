"""The policy's state machine: causes in, next state and command out (pure, clock passed in).

One step: (1) evidence -> causes (``causes.py``); (2) latch; (3) reset arbitration;
(4) clear timers on logical time; (5) the transition to the next phase; (6) speed window;
(7) the command. Each is a small pure function below.
"""

from __future__ import annotations

import math

from monitor.policy.causes import FrameCauses, fail_safe_causes, frame_causes, is_startup
from monitor.policy.model import (
    LEVEL_OF,
    MUTED_INSIDE,
    RUN,
    RUN_CLEAR,
    SLOW_ACTIVE,
    SLOW_CLEARING,
    STOP,
    STOP_ACTIVE,
    STOP_CLEARING,
    STOP_LATCHED,
    Command,
    Latch,
    PolicyConfig,
    PolicyInputs,
    PolicyState,
    Reason,
    ResetOutcome,
    ResetRequest,
)
from monitor.timetext import TimeText, seconds
from monitor.types import Fault

_STOP_PHASES = frozenset({STOP_ACTIVE, STOP_CLEARING, STOP_LATCHED})
CONFIRM_CLEAR_HINT = ("wait until the person is seen leaving, or `monitor reset --confirm-clear` "
                      "after looking")


def latch(current: Latch | None, stop_causes: tuple[Reason, ...], faults: tuple[Fault, ...],
          now: float, config: PolicyConfig, nonce: str = "") -> Latch | None:
    """The latch after this step's causes. Manual interlock: any STOP cause but the start-up
    one latches (that one and a camera waiting for its first frame too with
    ``startup_requires_reset``). A fault with ``latch=True`` latches always. An existing latch
    keeps its first cause (and nonce); a new one gets ``nonce``."""
    if current is not None:
        return current
    latching = [f for f in faults if f.latch]
    if latching:
        f = latching[0]
        return Latch("fault", f"{f.name}: {f.reason}", now, nonce=nonce)
    if config.restart_interlock != "manual":
        return None
    for r in stop_causes:
        if not is_startup(r) or config.startup_requires_reset:
            return Latch(r.code, r.message, now, r.zone_id, r.person, nonce)
    return None


def stale_latch(req: ResetRequest, current: Latch | None) -> str | None:
    """Why ``req`` is not bound to the latch ``current`` (None: bound, or made in-process).
    A reset names the nonce of the latch it releases: one made for an earlier latch, or in an
    earlier run of the monitor, never releases this one, whatever its age."""
    if req.latch is None or current is None:
        return None  # in-process request; or nothing latched (answered as such)
    if not req.latch:
        return ("refused: the request names no latch nonce (read it from the status while "
                "latched; `monitor reset` does)")
    if req.latch != current.nonce:
        return (f"refused: stale latch nonce {req.latch!r}: the STOP latched now has nonce "
                f"{current.nonce!r} (a reset made for an earlier latch or an earlier run of "
                "the monitor)")
    return None


def muted_inside(muted_stops: tuple[Reason, ...]) -> str:
    """Why a reset waits while muted protective zones hold persons, naming the zones."""
    zones = sorted({r.zone_id for r in muted_stops if r.zone_id}) or ["(unnamed)"]
    causes = "; ".join(r.message for r in muted_stops)
    return (f"muted zone{'s' if len(zones) > 1 else ''} {', '.join(zones)} not seen free "
            f"({causes}): a mute suspends a zone's STOP, it never makes a reset with a person "
            "inside acceptable; no reset until the muted zones are seen free")


def arbitrate_reset(req: ResetRequest | None, stop_causes: tuple[Reason, ...],
                    current: Latch | None, now: float, config: PolicyConfig,
                    muted_stops: tuple[Reason, ...] = ()
                    ) -> tuple[ResetOutcome | None, Latch | None]:
    """Accept a reset only when it is fresh, names this latch, the STOP is latched, no STOP
    cause holds and no muted zone holds a person (``muted_stops``: the STOP causes the mutes
    suspend)."""
    if req is None:
        return None, current
    age = now - req.time
    if not (abs(age) <= config.reset_max_age):
        return ResetOutcome(req.operator, False, f"refused: request is {age:.1f} s old",
                            req.request_id), current
    stale = stale_latch(req, current)
    if stale is not None:
        return ResetOutcome(req.operator, False, stale, req.request_id), current
    if stop_causes:
        text = "; ".join(r.message for r in stop_causes)
        if any(r.code == "person_lost" for r in stop_causes):
            text += f" ({CONFIRM_CLEAR_HINT})"
        return ResetOutcome(req.operator, False, "refused: " + text, req.request_id), current
    if muted_stops and current is not None:
        text = muted_inside(muted_stops)
        if any(r.code == "person_lost" for r in muted_stops):
            text += f" ({CONFIRM_CLEAR_HINT})"
        return ResetOutcome(req.operator, False, "refused: " + text, req.request_id), current
    if current is None:
        return ResetOutcome(req.operator, False, "nothing to reset: not latched",
                            req.request_id), None
    return ResetOutcome(req.operator, True, "reset accepted", req.request_id), None


def without_lost(seen: FrameCauses) -> FrameCauses:
    """The carried causes without those of lost persons (``person_lost``, and a lost person's
    warning zone: a warning reason with ``since``), after a confirm-clear dropped their holds.
    The speed scale stays (it is only ever lower than without them, for clear_time)."""
    return FrameCauses(tuple(r for r in seen.stops if r.code != "person_lost"),
                       tuple(r for r in seen.slows
                             if not (r.code == "warning_zone" and r.since is not None)),
                       seen.scale)


def has_cleared(seen: float | None, now: float, config: PolicyConfig) -> bool:
    """True when the cause last seen at ``seen`` has been absent for ``clear_time``."""
    return seen is None or now - seen >= config.clear_time


def next_phase(prev: str, has_stop: bool, has_slow: bool, stop_cleared: bool,
               slow_cleared: bool, latched: bool) -> str:
    """The transition: enter at once, leave STOP only unlatched and after clear_time, leave
    SLOW only after clear_time."""
    if has_stop:
        return STOP_ACTIVE
    if prev in _STOP_PHASES:
        if latched:
            return STOP_LATCHED
        if not stop_cleared:
            return STOP_CLEARING
    if has_slow:
        return SLOW_ACTIVE
    if prev != RUN_CLEAR and not slow_cleared:
        return SLOW_CLEARING
    return RUN_CLEAR


def speed_window(window: tuple[tuple[float, float], ...], wanted: float, now: float,
                 config: PolicyConfig) -> tuple[tuple[tuple[float, float], ...], float]:
    """Keep (time, wanted scale) of the last clear_time; the lowest one applies, so a lower
    scale applies at once and a higher one only after clear_time."""
    kept = (*(e for e in window if now - e[0] < config.clear_time), (now, wanted))
    return kept, min(s for _, s in kept)


def _clearing(seen: float, now: float, config: PolicyConfig) -> Reason:
    """Only while clearing: the cause was seen (``seen`` is a time)."""
    return Reason("clearing", f"causes absent for {now - seen:.3f} s of {config.clear_time} s")


def latch_reason(latched_by: Latch, holding: bool, slow_causes: tuple[Reason, ...],
                 when: TimeText, muted_stops: tuple[Reason, ...] = ()) -> Reason:
    """The latch as a reason. While a STOP cause holds, the causes before it say why (present
    tense, with their zones) and this one says a reset waits. Once none holds it is the
    command's only cause and says the latch's cause as a past event, at its time on the
    operator's clock (``when``), with the latch's zone: every output reads its reason and zone
    from the first reason
    (OPC UA ``Reason``, the Modbus ``reason``/``zone`` registers, the console), so none shows a
    person inside a cell that is clear. A person in a warning zone meanwhile is named (the
    cell is not clear then, though a reset is possible), and a muted zone that holds a person
    (``muted_stops``: then no reset until it is seen free)."""
    if holding:
        return Reason("latched", "STOP latched: waiting for an operator reset")
    now_text = "cell clear" if not (slow_causes or muted_stops) else "no STOP cause now" + (
        " (" + "; ".join(r.text(when) for r in slow_causes) + ")" if slow_causes else "")
    zones = sorted({r.zone_id for r in muted_stops if r.zone_id})
    possible = f"no reset until muted {', '.join(zones) or 'zones'} seen free" if muted_stops \
        else "reset possible"
    return Reason("latched", f"latched by {latched_by.message} at {when(latched_by.at)}; "
                  f"{now_text}, {possible}", zone_id=latched_by.zone_id)


def step(state: PolicyState, inputs: PolicyInputs, now: float,
         config: PolicyConfig, when: TimeText = seconds) -> tuple[PolicyState, Command]:
    """Advance the policy by one step at time ``now`` (seconds, monotonic). ``when`` writes a
    time of that clock in the operator's clock (live: the wall clock) in reason texts."""
    if not math.isfinite(now):
        raise ValueError(f"policy.step: now={now!r} is not finite")
    has_frame = inputs.frame_time is not None
    # no new frame is no evidence of a clear cell: carry the last frame's zone causes
    seen = frame_causes(inputs.zone_report) if has_frame else FrameCauses(
        state.frame_stops, state.frame_slows, state.frame_scale)
    if not has_frame and inputs.lost_dropped:
        seen = without_lost(seen)
    stop_causes = fail_safe_causes(inputs, now, config, state.last_frame, has_frame)
    # zone causes first: the person is what an operator must act on
    stop_causes = seen.stops + stop_causes
    slow_causes = seen.slows

    serial = state.latches + 1  # the serial of a latch that begins in this step
    latched_by = latch(state.latched_by, stop_causes, inputs.faults, now, config,
                       inputs.latch_nonce or f"latch-{serial}")
    latches = serial if latched_by is not None and state.latched_by is None else state.latches
    reset, latched_by = arbitrate_reset(inputs.reset_request, stop_causes, latched_by, now,
                                        config, inputs.muted_stops)
    stop_seen = now if stop_causes else state.stop_seen
    slow_seen = now if (stop_causes or slow_causes) else state.slow_seen
    stop_cleared = has_cleared(stop_seen, now, config)
    phase = next_phase(state.phase, bool(stop_causes), bool(slow_causes), stop_cleared,
                       has_cleared(slow_seen, now, config), latched_by is not None)
    level = LEVEL_OF[phase]
    if level != STOP:  # (a latch is only ever set with a STOP cause; never carry one out)
        latched_by = None

    reasons = {
        STOP_ACTIVE: stop_causes,
        SLOW_ACTIVE: slow_causes,
        RUN_CLEAR: (),
        # latched with no STOP cause: the causes before are history, said by the latch reason
        STOP_LATCHED: (latch_reason(latched_by, False, slow_causes, when, inputs.muted_stops),)
        if latched_by is not None else (),
    }.get(phase, state.hold_reasons)
    if phase in (STOP_CLEARING, STOP_LATCHED) and not stop_cleared:
        reasons += (_clearing(stop_seen, now, config),)
    elif phase == SLOW_CLEARING:
        reasons += (_clearing(slow_seen, now, config),)
    if latched_by is not None and phase != STOP_LATCHED:
        reasons += (latch_reason(latched_by, True, slow_causes, when),)
    reasons += inputs.mutes  # muted zones: said in every command while muted
    if latched_by is not None and inputs.muted_stops:  # why the reset waits (after the mutes)
        reasons += (Reason(MUTED_INSIDE, muted_inside(inputs.muted_stops),
                           zone_id=inputs.muted_stops[0].zone_id),)

    # (1.0 without a SLOW cause; a STOP's own entry would expire before STOP can be left)
    window, lowest = speed_window(state.scale_window, seen.scale, now, config)
    speed = {STOP: 0.0, RUN: 1.0}.get(level, lowest)

    since = now if (state.since is None or level != state.state) else state.since
    hold = {STOP_ACTIVE: stop_causes, SLOW_ACTIVE: slow_causes, RUN_CLEAR: ()}.get(
        phase, state.hold_reasons)
    reset_possible = latched_by is not None and not stop_causes and not inputs.muted_stops
    possible_since = (state.reset_possible_since if state.reset_possible_since is not None
                      else now) if reset_possible else None
    new_state = PolicyState(
        phase=phase, since=since, latched_by=latched_by, stop_seen=stop_seen,
        slow_seen=slow_seen, scale_window=window,
        last_frame=now if has_frame else state.last_frame,
        frame_stops=seen.stops,
        frame_slows=seen.slows, frame_scale=seen.scale, hold_reasons=hold,
        last_reset=reset or state.last_reset, reset_possible_since=possible_since,
        latches=latches,
    )
    command = Command(
        state=level, speed_scale=speed, reasons=reasons, since=since,
        latched=latched_by is not None, reset=reset, latched_by=latched_by,
        reset_possible=reset_possible, reset_possible_since=possible_since,
        clear_for_s=None if stop_causes or stop_seen is None else now - stop_seen,
        phase=phase,
    )
    return new_state, command
