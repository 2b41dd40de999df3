"""The policy's data: configuration, evidence in, command out, and the state between steps.

Times are seconds on the clock passed to ``step`` (monotonic live, the video's clock in replay).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from monitor.schema import Bool, Seconds, section
from monitor.timetext import TimeText, seconds
from monitor.types import Fault, ZoneReport

RUN, SLOW, STOP = "RUN", "SLOW", "STOP"

# The machine's states (``PolicyState.phase``). Each maps onto one command level.
RUN_CLEAR = "RUN"  # no cause, nothing clearing
SLOW_ACTIVE = "SLOW_ACTIVE"  # a SLOW cause is present
SLOW_CLEARING = "SLOW_CLEARING"  # SLOW causes gone, waiting clear_time
STOP_ACTIVE = "STOP_ACTIVE"  # a STOP cause is present
STOP_CLEARING = "STOP_CLEARING"  # STOP causes gone, waiting clear_time (not latched)
STOP_LATCHED = "STOP_LATCHED"  # STOP causes gone, waiting for an operator reset
# the reason of a latched STOP whose reset waits for a muted zone to be seen free
MUTED_INSIDE = "muted_inside"
PHASES = (RUN_CLEAR, SLOW_ACTIVE, SLOW_CLEARING, STOP_ACTIVE, STOP_CLEARING, STOP_LATCHED)
LEVEL_OF = {RUN_CLEAR: RUN, SLOW_ACTIVE: SLOW, SLOW_CLEARING: SLOW, STOP_ACTIVE: STOP,
            STOP_CLEARING: STOP, STOP_LATCHED: STOP}


@section("policy")
class PolicyConfig:
    """Policy timing and limits. Times in seconds (positive and finite)."""

    clear_time: Seconds = 1.0  # a cause must be absent this long before the level drops
    # "manual": STOP latches until reset; "auto": no latch
    restart_interlock: Literal["manual", "auto"] = "manual"
    frame_timeout: Seconds = 0.5  # no frame processed for this long -> STOP
    max_frame_age: Seconds = 0.3  # frame captured longer ago than this at decision time -> STOP
    pose_timeout: Seconds = 0.1  # newest accepted pose older than this -> STOP (separation on)
    separation_monitoring: Bool = False  # use the tool pose and ISO/TS 15066 separation
    reset_max_age: Seconds = 2.0  # a reset request older than this (since arrival) is ignored
    startup_requires_reset: Bool = False  # manual interlock also latches the start-up STOP


@dataclass(frozen=True)
class Reason:
    """Why the command is what it is. ``code`` is a stable name for machines.

    STOP codes: ``protective_zone``, ``person_lost`` (a tracked person lost inside a protective
    zone), ``separation`` (closer than S_p, or a separation speed scale of 0 or unknown),
    ``fault``, ``detector_error``, ``frame_timeout``, ``frame_stale``, ``pose_stale``,
    ``zone_invalid``, ``startup``. SLOW codes: ``warning_zone``, ``separation_speed``
    (v_max(separation) below the programmed speed). Notes: ``muted`` (a zone muted by an
    operator, in every command while it holds; docs/muting.md). Bookkeeping: ``clearing``
    (cause gone, waiting ``clear_time``), ``latched`` (waiting for a reset; with no STOP cause
    now the first reason, saying the latch's cause as past, with its zone), ``shutdown`` and
    ``stalled`` (added by the bus). ``person`` is the cell person's id when the person is
    tracked (``monitor.tracking.cell_persons``: a number, or "cam1:4" on an uncalibrated camera of
    several), else the row.
    """

    code: str
    message: str
    zone_id: str | None = None
    person: int | str | None = None
    distance_m: float | None = None
    required_m: float | None = None
    fault: str | None = None
    source: str | None = None
    since: float | None = None  # when the cause began (a person lost: when last seen)

    def text(self, when: TimeText = seconds) -> str:
        """The message, with its start time in the operator's clock (``when``)."""
        return self.message if self.since is None else f"{self.message} since {when(self.since)}"

    def key(self) -> tuple:
        """Identity of the cause, without the values that change every frame."""
        return (self.code, self.zone_id, self.person, self.fault, self.source)

    def to_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if v is not None}


@dataclass(frozen=True)
class Latch:
    """The cause that latched the STOP, and when (s). ``nonce`` names this latch: a reset must
    name it (``ResetRequest.latch``), so a reset made for another latch or another run of the
    monitor never releases this one (``monitor.wire.resets.LatchNonces`` makes them live)."""

    code: str
    message: str
    at: float
    zone_id: str | None = None
    person: int | str | None = None
    nonce: str = ""

    def to_dict(self) -> dict:
        return {"code": self.code, "message": self.message, "zone_id": self.zone_id,
                "person": self.person, "at": self.at, "nonce": self.nonce}


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
    # the nonce of the latch this request releases (every request from the bus names one);
    # None only for requests made inside the process (replay's reset times, tests)
    latch: str | None = None


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
    ``frame_source``: the camera whose frame ``frame_time`` is (with several cameras, the one
    furthest behind), so a stale-frame STOP names it.
    """

    frame_time: float | None = None
    zone_report: ZoneReport | None = None
    faults: tuple[Fault, ...] = ()
    detector_error: str | None = None
    pose_time: float | None = None
    zone_error: str | None = None
    reset_request: ResetRequest | None = None
    frame_source: str | None = None
    # the nonce a latch that begins in this step gets (the caller derives it from the boot and
    # the latch's serial, ``PolicyState.latches + 1``); empty: ``latch-<serial>`` (replay)
    latch_nonce: str = ""
    # the zones muted at this step, one ``Reason("muted", ...)`` each (the caller has already
    # applied the mutes to ``zone_report``): shown in every command while they hold
    mutes: tuple[Reason, ...] = ()
    # the STOP causes a mute suspends at this step (a person in a muted protective zone, from
    # the zone answer before the mutes): no STOP of their own, but a reset is refused while
    # any holds, naming them (the scanners' rule: muting suspends a field, it never makes a
    # reset with a person inside acceptable; docs/muting.md)
    muted_stops: tuple[Reason, ...] = ()
    # an operator's confirm-clear dropped every lost person's hold before this step: a step
    # without a frame, which carries the last frame's causes, carries them without the lost
    # persons (so the confirm-clear's own reset is judged without them: one step)
    lost_dropped: bool = False


@dataclass(frozen=True)
class Command:
    """What the robot controller should do. ``speed_scale`` is 1.0 for RUN, 0.0 for STOP.

    ``reset_possible``: latched and no STOP cause now (a reset would be accepted);
    ``reset_possible_since`` when that became true; ``clear_for_s`` how long the cell has shown
    no STOP cause (None while one holds).
    """

    state: str
    speed_scale: float
    reasons: tuple[Reason, ...] = ()
    since: float = 0.0  # when this state was entered (s, same clock as ``now``)
    latched: bool = False  # STOP waits for an operator reset
    reset: ResetOutcome | None = None  # outcome of a reset request handled in this step
    latched_by: Latch | None = None
    reset_possible: bool = False
    reset_possible_since: float | None = None
    clear_for_s: float | None = None
    phase: str = ""  # the machine's state (``PHASES``); empty for commands made elsewhere
    # the zone sets applying (two or more while switching; docs/cases.md); () without sets
    zone_sets: tuple[str, ...] = ()

    def same_as(self, other: Command | None) -> bool:
        """True when nothing a controller or operator acts on changed: same state, speed,
        latch, reset possibility and reasons by (code, zone, person, fault). Messages,
        distances and ``clear_for_s`` that move every frame do not count; the heartbeat
        carries their newest values."""
        return (
            other is not None
            and self.state == other.state
            and self.speed_scale == other.speed_scale
            and self.latched == other.latched
            and self.reset_possible == other.reset_possible
            and [r.key() for r in self.reasons] == [r.key() for r in other.reasons]
            and self.zone_sets == other.zone_sets
        )

    def describe(self, when: TimeText = seconds) -> str:
        """The one line for an operator: the latch's cause, what holds now, and whether a
        reset is possible, never contradicting each other. ``when`` turns a time on the
        policy's clock into text (wall clock live, video seconds in replay). E.g.
        ``STOP latched by person 0 in robot-protective at 14:03:12; no STOP cause now (clear
        for 2.3 s): reset possible``."""
        # in the *_CLEARING and STOP_LATCHED phases the reasons are the causes that held
        # before (shown as "was"); in the others they hold now. No phase: made elsewhere.
        holding = self.phase in ("", STOP_ACTIVE, SLOW_ACTIVE)
        causes = "; ".join(r.text(when) for r in self.reasons
                           if r.code not in ("clearing", "latched"))
        clearing = next((r.message for r in self.reasons if r.code == "clearing"), None)
        if self.latched:
            head = "STOP latched"
            if self.latched_by is not None:
                head += f" by {self.latched_by.message} at {when(self.latched_by.at)}"
            if holding and causes:
                return f"{head}; holding now: {causes}; no reset until they clear"
            if self.reset_possible:
                clear = f" (clear for {self.clear_for_s:.1f} s)" \
                    if self.clear_for_s is not None else ""
                return f"{head}; no STOP cause now{clear}: reset possible"
            inside = "; ".join(r.text(when) for r in self.reasons if r.code == MUTED_INSIDE)
            if inside:
                return f"{head}; {inside}"
            return f"{head}; waiting for an operator reset"
        if self.state == RUN:
            return "RUN"
        head = STOP if self.state == STOP else f"SLOW x{self.speed_scale:.2f}"
        if holding:
            return f"{head}: {causes or 'no cause given'}"
        was = f" (was: {causes})" if causes else ""
        return f"{head}: clearing, {clearing or 'causes absent'}{was}"

    def to_dict(self) -> dict:
        out = {
            "state": self.state,
            "speed_scale": self.speed_scale,
            "reasons": [r.to_dict() for r in self.reasons],
            "since": self.since,
            "latched": self.latched,
            "reset_possible": self.reset_possible,
            "clear_for_s": self.clear_for_s,
        }
        if self.latched_by is not None:
            out["latched_by"] = self.latched_by.to_dict()
        if self.reset_possible_since is not None:
            out["reset_possible_since"] = self.reset_possible_since
        if self.reset is not None:
            out["reset"] = dict(self.reset.__dict__)
        if self.zone_sets:
            out["zone_sets"] = list(self.zone_sets)
        return out


@dataclass(frozen=True)
class PolicyState:
    """Everything the policy remembers between steps."""

    phase: str = STOP_ACTIVE
    since: float | None = None  # when the current level was entered; None until the first step
    latched_by: Latch | None = None  # None: not latched
    stop_seen: float | None = None  # last time a STOP cause was present
    slow_seen: float | None = None  # last time any SLOW or STOP cause was present
    scale_window: tuple[tuple[float, float], ...] = ()  # (time, wanted scale), last clear_time
    last_frame: float | None = None  # ``now`` of the last step that processed a frame
    frame_stops: tuple[Reason, ...] = ()  # zone STOP causes of the last frame, carried over
    frame_slows: tuple[Reason, ...] = ()  # zone SLOW causes of the last frame, carried over
    frame_scale: float = 1.0  # speed scale asked by the last frame's SLOW causes
    hold_reasons: tuple[Reason, ...] = ()  # causes of the current level, shown while clearing
    last_reset: ResetOutcome | None = None
    reset_possible_since: float | None = None
    latches: int = 0  # latches begun so far (the serial of the newest one)

    @property
    def state(self) -> str:
        """The command level (RUN / SLOW / STOP) of the current phase."""
        return LEVEL_OF[self.phase]

    @property
    def latched(self) -> bool:
        return self.latched_by is not None


def initial_state() -> PolicyState:
    """STOP: nothing is known until frames arrive (every step before the first frame, and the
    step of that frame, has the cause ``startup``)."""
    return PolicyState()
