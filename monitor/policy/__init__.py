"""Safety policy: turns one step of evidence into a RUN / SLOW / STOP command.

Pure: no I/O, no clock. ``step(state, inputs, now, config)`` takes the time ``now`` (seconds on
the monotonic clock, or the video's clock in replay) and returns the new state and the command, so
a replay gives the same commands every time. The policy is an explicit state machine
(``machine.py``) over named causes (``causes.py``); docs/policy.md has the transition table.

Rules (the monitor is a supplementary device; it fails towards STOP):

* Enter SLOW or STOP on the first step that shows the cause (no debounce in the safe direction).
* Leave only after every cause of that level has been absent for ``clear_time`` (asymmetric
  hysteresis). A raised speed scale also waits ``clear_time``; a lowered one applies at once.
* ``restart_interlock="manual"``: every STOP except the start-up STOP latches; a fault with
  ``latch=True`` latches with either interlock. A latch is left only when a reset request
  arrives while no STOP cause is present, and the causes then stay absent for ``clear_time``.
  A reset while a cause is present is refused with that cause as the reason. Each latch has a
  nonce (``PolicyInputs.latch_nonce``, made by the caller from the boot and the latch serial);
  a reset naming another nonce is refused as stale (``ResetRequest.latch``).
* Zone causes: a person in a protective zone (or a warning zone with speed scale 0) and a
  tracked person lost inside one (``person_lost``) STOP; a person in a warning zone SLOWs at the
  zone's scale; ``separation_speed_scale`` <= 0 or NaN STOPs (``separation``), < 1 SLOWs at that
  scale (``separation_speed``); a separation below the required one, or a NaN/inf one, STOPs.
  The commanded speed is the lowest scale asked within the last ``clear_time``.
* Fail-safe STOP causes: no frame processed for ``frame_timeout``; the detector raised; the frame
  is older than ``max_frame_age`` at decision time (or its time is NaN); the pose stream is stale
  while separation monitoring is on; the zone file is invalid; any health fault with ``stop=True``.
* Start-up: the monitor starts in STOP (reason ``startup``) and does not latch for it: it leaves
  STOP after good frames have shown a clear cell for ``clear_time`` (set
  ``startup_requires_reset=True`` to demand a reset at start-up too). The robot controller's own
  start after power-up is still needed; this monitor never starts motion by itself.
* A step without a frame (``frame_time=None``) only evaluates timers and current faults. The zone
  causes of the last frame are carried over, so a cell is never declared clear without a frame
  that shows it clear.

May import: the bottom layer only (``types``, ``schema``, ``timetext``).
"""

from monitor.policy.causes import fail_safe_causes, frame_causes
from monitor.policy.machine import (
    arbitrate_reset,
    latch,
    next_phase,
    speed_window,
    stale_latch,
    step,
)
from monitor.policy.model import (
    LEVEL_OF,
    PHASES,
    RUN,
    RUN_CLEAR,
    SLOW,
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
    initial_state,
)

__all__ = [
    "LEVEL_OF", "PHASES", "RUN", "RUN_CLEAR", "SLOW", "SLOW_ACTIVE", "SLOW_CLEARING", "STOP",
    "STOP_ACTIVE", "STOP_CLEARING", "STOP_LATCHED", "Command", "Latch", "PolicyConfig",
    "PolicyInputs", "PolicyState", "Reason", "ResetOutcome", "ResetRequest", "arbitrate_reset",
    "fail_safe_causes", "frame_causes", "initial_state", "latch", "next_phase", "speed_window",
    "stale_latch", "step",
]
