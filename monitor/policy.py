"""Safety policy: turns one step of evidence into a RUN / SLOW / STOP command.

Pure: no I/O, no clock. ``step(state, inputs, now, config)`` takes the time ``now`` (seconds on
the monotonic clock, or the video's clock in replay) and returns the new state and the command, so
a replay gives the same commands every time.

Rules (the monitor is a supplementary device; it fails towards STOP):

* Enter SLOW or STOP on the first step that shows the cause (no debounce in the safe direction).
* Leave only after every cause of that level has been absent for ``clear_time`` (asymmetric
  hysteresis). A raised speed scale also waits ``clear_time``; a lowered one applies at once.
* ``restart_interlock="manual"``: every STOP except the start-up STOP latches. It is left only
  when a reset request arrives while no STOP cause is present, and the causes then stay absent
  for ``clear_time``. A reset while a cause is present is refused with that cause as the reason.
* Fail-safe STOP causes: no frame processed for ``frame_timeout``; the detector raised; the frame
  is older than ``max_frame_age`` at decision time; the pose stream is stale while separation
  monitoring is on; the zone file is invalid; any health fault with ``stop=True``.
* Start-up: the monitor starts in STOP (reason ``startup``) and does not latch for it: it leaves
  STOP after good frames have shown a clear cell for ``clear_time`` (set
  ``startup_requires_reset=True`` to demand a reset at start-up too). The robot controller's own
  start after power-up is still needed; this monitor never starts motion by itself.
* A step without a frame (``frame_time=None``) only evaluates timers and current faults. The zone
  causes of the last frame are carried over, so a cell is never declared clear without a frame
  that shows it clear.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from monitor.errors import ConfigError
from monitor.types import Fault, ZoneReport

RUN, SLOW, STOP = "RUN", "SLOW", "STOP"
_LEVEL = {RUN: 0, SLOW: 1, STOP: 2}


@dataclass(frozen=True)
class PolicyConfig:
    """Policy timing and limits. Times in seconds, distances in metres."""

    clear_time: float = 1.0  # a cause must be absent this long before the level drops
    restart_interlock: str = "manual"  # "manual": STOP latches until reset; "auto": no latch
    frame_timeout: float = 0.5  # no frame processed for this long -> STOP
    max_frame_age: float = 0.3  # frame captured longer ago than this at decision time -> STOP
    pose_timeout: float = 0.1  # newest accepted pose older than this -> STOP (separation on)
    separation_monitoring: bool = False  # use the tool pose and ISO/TS 15066 separation
    separation_slow_margin_m: float = 0.5  # SLOW while separation < required + margin
    separation_slow_scale: float = 0.3  # speed scale while inside that margin
    reset_max_age: float = 2.0  # a reset request older than this (since arrival) is ignored
    startup_requires_reset: bool = False  # manual interlock also latches the start-up STOP

    def __post_init__(self) -> None:
        if self.restart_interlock not in ("manual", "auto"):
            raise ConfigError(
                f"policy.restart_interlock: {self.restart_interlock!r} is not 'manual' or 'auto'"
            )
        for name in ("clear_time", "frame_timeout", "max_frame_age", "pose_timeout",
                     "reset_max_age"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"policy.{name}: must be a positive number of seconds, "
                                  f"got {value!r}")
        if not (math.isfinite(self.separation_slow_margin_m)
                and self.separation_slow_margin_m >= 0):
            raise ConfigError("policy.separation_slow_margin_m: must be >= 0 metres")
        if not 0.0 <= self.separation_slow_scale <= 1.0:
            raise ConfigError("policy.separation_slow_scale: must be within [0, 1]")


@dataclass(frozen=True)
class Reason:
    """Why the command is what it is. ``code`` is a stable name for machines.

    Codes: ``protective_zone``, ``warning_zone``, ``separation``, ``separation_margin``,
    ``fault``, ``detector_error``, ``frame_timeout``, ``frame_stale``, ``pose_stale``,
    ``zone_invalid``, ``startup``, ``clearing`` (cause gone, waiting ``clear_time``),
    ``latched`` (waiting for a reset), ``shutdown``, ``stalled`` (added by the bus).
    """

    code: str
    message: str
    zone_id: str | None = None
    person: int | None = None
    distance_m: float | None = None
    required_m: float | None = None
    fault: str | None = None
    source: str | None = None

    def key(self) -> tuple:
        """Identity of the cause, without the values that change every frame."""
        return (self.code, self.zone_id, self.person, self.fault, self.source)

    def to_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if v is not None}


@dataclass(frozen=True)
class ResetRequest:
    """An operator's request to release a latched STOP (from ``safety/reset``).

    ``time`` is when it arrived, on the monitor's monotonic clock (not the sender's clock).
    """

    operator: str
    time: float
    request_id: str = ""
    note: str = ""
    # the operator has looked and confirms the cell is clear: releases holds of persons lost
    # inside a zone (never a person who is seen); logged and alerted by the pipeline
    confirm_clear: bool = False


@dataclass(frozen=True)
class ResetOutcome:
    """What happened to a reset request in this step."""

    operator: str
    accepted: bool
    message: str
    request_id: str = ""


@dataclass(frozen=True)
class PolicyInputs:
    """Evidence for one step.

    ``frame_time``: capture time (s, monotonic) of the frame processed in this step, or None when
    the step only evaluates timers. ``zone_report``: zone answer for that frame (None = no frame,
    or zones not evaluated). ``pose_time``: receive time (s, monotonic) of the newest accepted
    tool pose, None if none yet. ``zone_error``: set when the zone file is invalid.
    """

    frame_time: float | None = None
    zone_report: ZoneReport | None = None
    faults: tuple[Fault, ...] = ()
    detector_error: str | None = None
    pose_time: float | None = None
    zone_error: str | None = None
    reset_request: ResetRequest | None = None


@dataclass(frozen=True)
class Command:
    """What the robot controller should do. ``speed_scale`` is 1.0 for RUN, 0.0 for STOP."""

    state: str
    speed_scale: float
    reasons: tuple[Reason, ...] = ()
    since: float = 0.0  # when this state was entered (s, same clock as ``now``)
    latched: bool = False  # STOP waits for an operator reset
    reset: ResetOutcome | None = None  # outcome of a reset request handled in this step

    def same_as(self, other: Command | None) -> bool:
        """True when nothing a controller or operator acts on changed: same state, speed,
        latch and reasons by (code, zone, person, fault). Messages and distances that move
        every frame do not count; the heartbeat carries their newest values."""
        return (
            other is not None
            and self.state == other.state
            and self.speed_scale == other.speed_scale
            and self.latched == other.latched
            and [r.key() for r in self.reasons] == [r.key() for r in other.reasons]
        )

    def to_dict(self) -> dict:
        out = {
            "state": self.state,
            "speed_scale": self.speed_scale,
            "reasons": [r.to_dict() for r in self.reasons],
            "since": self.since,
            "latched": self.latched,
        }
        if self.reset is not None:
            out["reset"] = dict(self.reset.__dict__)
        return out


@dataclass(frozen=True)
class PolicyState:
    """Everything the policy remembers between steps."""

    state: str = STOP
    since: float | None = None  # None until the first step
    latched: bool = False
    stop_seen: float | None = None  # last time a STOP cause was present
    slow_seen: float | None = None  # last time any SLOW or STOP cause was present
    scale_window: tuple[tuple[float, float], ...] = ()  # (time, wanted scale), last clear_time
    last_frame: float | None = None  # ``now`` of the last step that processed a frame
    frame_reasons: tuple[Reason, ...] = ()  # zone causes of the last frame, carried over
    frame_scale: float = 1.0  # speed scale asked by the last frame's SLOW causes
    hold_reasons: tuple[Reason, ...] = ()  # causes of the current level, shown while clearing
    last_reset: ResetOutcome | None = None


def initial_state() -> PolicyState:
    """STOP with reason ``startup``: nothing is known until frames arrive."""
    return PolicyState(hold_reasons=(Reason("startup", "no frame processed yet"),))


def _frame_causes(report: ZoneReport | None, config: PolicyConfig
                  ) -> tuple[tuple[Reason, ...], tuple[Reason, ...], float]:
    """STOP causes, SLOW causes and the SLOW speed scale shown by one frame's zone report."""
    stops: list[Reason] = []
    slows: list[Reason] = []
    scale = 1.0
    if report is None:
        return (), (), 1.0
    # a stable order (zone, person): the same causes in another order are no change to announce
    for hit in sorted(report.hits, key=lambda h: (h.zone_id, h.person)):
        if hit.kind == "protective" or hit.speed_scale <= 0.0:
            stops.append(Reason("protective_zone", f"person {hit.person} in zone {hit.zone_id}",
                                zone_id=hit.zone_id, person=hit.person,
                                distance_m=hit.distance_m))
        else:
            slows.append(Reason("warning_zone", f"person {hit.person} in zone {hit.zone_id}",
                                zone_id=hit.zone_id, person=hit.person,
                                distance_m=hit.distance_m))
            scale = min(scale, hit.speed_scale)
    sep, req = report.tool_separation_m, report.required_separation_m
    if config.separation_monitoring and sep is not None and req is not None:
        if not math.isfinite(sep) or sep < req:
            stops.append(Reason("separation", f"separation {sep:.3f} m < required {req:.3f} m",
                                distance_m=sep, required_m=req))
        elif sep < req + config.separation_slow_margin_m:
            slows.append(Reason("separation_margin",
                                f"separation {sep:.3f} m within {config.separation_slow_margin_m}"
                                f" m of required {req:.3f} m", distance_m=sep, required_m=req))
            scale = min(scale, config.separation_slow_scale)
    return tuple(stops), tuple(slows), scale


def _fail_safe_causes(inputs: PolicyInputs, now: float, config: PolicyConfig,
                      prev_frame: float | None, last_frame: float | None) -> list[Reason]:
    causes: list[Reason] = []
    if prev_frame is None:  # this step's frame (if any) is the first: start-up STOP holds
        causes.append(Reason("startup", "no frame processed yet" if last_frame is None
                             else "first frame: watching the cell for clear_time"))
    elif last_frame is not None and now - last_frame > config.frame_timeout:
        causes.append(Reason("frame_timeout",
                             f"no frame for {now - last_frame:.3f} s (> {config.frame_timeout} s)"))
    if inputs.frame_time is not None and (
        not math.isfinite(inputs.frame_time) or now - inputs.frame_time > config.max_frame_age
    ):
        causes.append(Reason("frame_stale", f"frame is {now - inputs.frame_time:.3f} s old "
                             f"(> {config.max_frame_age} s)"))
    if inputs.detector_error:
        causes.append(Reason("detector_error", inputs.detector_error, fault="detector_error",
                             source="detector"))
    if inputs.zone_error:
        causes.append(Reason("zone_invalid", inputs.zone_error, fault="zone_invalid",
                             source="zones"))
    if config.separation_monitoring:
        if inputs.pose_time is None:
            causes.append(Reason("pose_stale", "no tool pose received", fault="pose_stale",
                                 source="pose"))
        elif now - inputs.pose_time > config.pose_timeout:
            causes.append(Reason("pose_stale", f"tool pose is {now - inputs.pose_time:.3f} s old "
                                 f"(> {config.pose_timeout} s)", fault="pose_stale",
                                 source="pose"))
    for fault in inputs.faults:
        if fault.stop:
            causes.append(Reason("fault", f"{fault.name}: {fault.reason}", fault=fault.name,
                                 source=fault.source or None))
    return causes


_ZONE_STOP_CODES = ("protective_zone", "separation")


def step(state: PolicyState, inputs: PolicyInputs, now: float,
         config: PolicyConfig) -> tuple[PolicyState, Command]:
    """Advance the policy by one step at time ``now`` (seconds, monotonic)."""
    if not math.isfinite(now):
        raise ValueError(f"policy.step: now={now!r} is not finite")
    has_frame = inputs.frame_time is not None
    last_frame = now if has_frame else state.last_frame
    if has_frame:
        zone_stops, zone_slows, frame_scale = _frame_causes(inputs.zone_report, config)
        frame_reasons = zone_stops + zone_slows
    else:  # carry the last frame's zone causes: no new frame is no evidence of a clear cell
        frame_reasons, frame_scale = state.frame_reasons, state.frame_scale
        zone_stops = tuple(r for r in frame_reasons if r.code in _ZONE_STOP_CODES)
        zone_slows = tuple(r for r in frame_reasons if r.code not in _ZONE_STOP_CODES)

    stop_causes = tuple(_fail_safe_causes(inputs, now, config, state.last_frame, last_frame))
    stop_causes += zone_stops
    slow_causes = zone_slows
    stop_seen = now if stop_causes else state.stop_seen
    slow_seen = now if (stop_causes or slow_causes) else state.slow_seen

    latched = state.latched
    if config.restart_interlock == "manual" and stop_causes and (
        config.startup_requires_reset or any(r.code != "startup" for r in stop_causes)
    ):
        latched = True

    reset_outcome = None
    req = inputs.reset_request
    if req is not None:
        if now - req.time > config.reset_max_age:
            reset_outcome = ResetOutcome(
                req.operator, False, f"refused: request is {now - req.time:.1f} s old",
                req.request_id)
        elif stop_causes:
            reset_outcome = ResetOutcome(
                req.operator, False, "refused: " + "; ".join(r.message for r in stop_causes),
                req.request_id)
        elif not latched:
            reset_outcome = ResetOutcome(req.operator, False, "nothing to reset: not latched",
                                         req.request_id)
        else:
            latched = False
            reset_outcome = ResetOutcome(req.operator, True, "reset accepted", req.request_id)

    # The level the evidence allows, with hysteresis towards the less restrictive levels.
    stop_clearing = stop_seen is not None and now - stop_seen < config.clear_time
    slow_clearing = slow_seen is not None and now - slow_seen < config.clear_time
    if stop_causes:
        level, reasons = STOP, stop_causes
    elif state.state == STOP and (stop_clearing or latched):
        level, reasons = STOP, state.hold_reasons
        if stop_clearing:
            reasons += (Reason("clearing", f"causes absent for {now - stop_seen:.3f} s "
                               f"of {config.clear_time} s"),)
    elif slow_causes:
        level, reasons = SLOW, slow_causes
    elif state.state in (SLOW, STOP) and slow_clearing:
        clearing = Reason("clearing", f"causes absent for {now - slow_seen:.3f} s "
                          f"of {config.clear_time} s")
        level, reasons = SLOW, (*state.hold_reasons, clearing)
    else:
        level, reasons = RUN, ()
    latched = latched and level == STOP
    if latched:
        reasons += (Reason("latched", "STOP latched: waiting for an operator reset"),)

    # Speed scale: the lowest one asked within the last clear_time (lowers at once, rises late).
    wanted = 0.0 if stop_causes else (frame_scale if slow_causes else 1.0)
    window = tuple(e for e in state.scale_window if now - e[0] < config.clear_time)
    window += ((now, wanted),)
    speed = {STOP: 0.0, RUN: 1.0}.get(level, min(s for _, s in window))

    since = now if (state.since is None or level != state.state) else state.since
    if level == RUN:
        hold: tuple[Reason, ...] = ()
    elif level == STOP and stop_causes:
        hold = stop_causes
    elif level == SLOW and slow_causes:
        hold = slow_causes
    else:
        hold = state.hold_reasons
    new_state = PolicyState(
        state=level, since=since, latched=latched, stop_seen=stop_seen, slow_seen=slow_seen,
        scale_window=window, last_frame=last_frame, frame_reasons=frame_reasons,
        frame_scale=frame_scale, hold_reasons=hold, last_reset=reset_outcome or state.last_reset,
    )
    command = Command(state=level, speed_scale=speed, reasons=reasons, since=since,
                      latched=latched, reset=reset_outcome)
    return new_state, command


@dataclass
class PolicyRunner:
    """Convenience wrapper keeping the state between steps (the service's one mutable holder)."""

    config: PolicyConfig = field(default_factory=PolicyConfig)
    state: PolicyState = field(default_factory=initial_state)

    def step(self, inputs: PolicyInputs, now: float) -> Command:
        self.state, command = step(self.state, inputs, now, self.config)
        return command


__all__ = [
    "RUN", "SLOW", "STOP", "Command", "PolicyConfig", "PolicyInputs", "PolicyRunner",
    "PolicyState", "Reason", "ResetOutcome", "ResetRequest", "initial_state", "step",
]
