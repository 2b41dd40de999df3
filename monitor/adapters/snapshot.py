"""What every robot-side output shows: one snapshot of the consumer rule's verdict per tick."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

from monitor.wire.consumer import Verdict

STATE_CODE = {"STOP": 0, "SLOW": 1, "RUN": 2}  # register / variable values of the state
# notes a command carries in its reasons while they hold, after the causes: never the cause of
# its state, so never its reason code or zone (a clean RUN with a muted zone, or watched by the
# test model, reads reason "" / 0, not "any other code")
# ("test_model" is monitor.detector.test_model.TEST_MODEL_REASON, spelled here: importing it
# loads the detector package, 0.5 s, into every adapter; tests check the two agree)
NOTE_CODES = frozenset({"muted", "test_model"})


@dataclass(frozen=True)
class SafetySnapshot:
    """The verdict of the consumer rule at one tick, for outputs (pure data).

    ``state`` and ``speed_scale`` are the VERDICT (STOP on silence, a bad signature, a stale or
    duplicate monitor), never the raw command. ``counter`` grows by one every tick, so a reader
    sees the adapter alive (the heartbeat); ``age_ms`` is the age of the last verified command
    (None: none yet). ``reason_code`` is the verdict's code when the adapter overrides the
    command ("no_command", "ttl", "sequence", "liveliness", "duplicate_monitor"), else the
    code of the command's first reason that is not a note (``NOTE_CODES``; "" for a clean RUN).
    """

    state: str
    speed_scale: float
    latched: bool
    reset_possible: bool
    reason_code: str
    reason: str
    zone_id: str | None
    seq: int | None
    age_ms: float | None
    counter: int
    mono: float  # the adapter's monotonic clock when this snapshot was made (s)
    wall: float  # the adapter's wall clock then (Unix s)
    faults: tuple[str, ...] = ()  # fault names among the command's reasons
    cameras: dict[str, bool] = field(default_factory=dict)  # camera id -> no camera fault
    cell: str = ""
    instance: str = ""  # the monitor followed
    zone_hash: str = ""  # the command's config_hash: the zone set in force
    zone_sets: tuple[str, ...] = ()  # the zone sets the command says apply (both: switching)

    @property
    def state_code(self) -> int:
        return STATE_CODE[self.state]


class Output(Protocol):
    """A robot-side output. ``publish`` is called every tick with the newest snapshot and must
    not block (store it; serve it from the protocol's own thread). ``close`` releases it."""

    name: str

    def publish(self, snapshot: SafetySnapshot) -> None: ...

    def close(self) -> None: ...


def _reasons(command: dict | None) -> list[dict]:
    items = (command or {}).get("reasons")
    return [r for r in items if isinstance(r, dict)] if isinstance(items, list) else []


def snapshot_of(verdict: Verdict, now: float, wall: float, counter: int,
                received: float | None, cameras: tuple[str, ...] = ()) -> SafetySnapshot:
    """The snapshot of ``verdict`` at ``now`` (monotonic s). ``received``: when the last
    verified command arrived (same clock); ``cameras``: the camera ids to report ok bits for
    (a camera is not ok while a reason of the command names it as a fault's source, or while
    the verdict is an override: then nothing is known)."""
    # an override knows nothing of the command's reasons: no reason code, zone or zone sets
    cmd = verdict.command if not verdict.code else None
    reasons = _reasons(cmd)
    first = next((r for r in reasons if r.get("code") not in NOTE_CODES), {})
    overridden = bool(verdict.code)
    scale = float(verdict.speed_scale)
    state = verdict.state
    if state not in STATE_CODE or not math.isfinite(scale) or not 0.0 <= scale <= 1.0:
        state = "STOP"  # cannot happen with a validated command; never RUN (scale 0 below)
    faults = tuple(str(r.get("fault")) for r in reasons if r.get("fault"))
    sources = {str(r.get("source")) for r in reasons if r.get("fault") and r.get("source")}
    age = None if received is None or verdict.command is None else (now - received) * 1000.0
    body = verdict.command or {}
    return SafetySnapshot(
        state=state, speed_scale=scale if state != "STOP" else 0.0,
        latched=bool(body.get("latched")),  # the last known latch, also while overridden
        reset_possible=bool(body.get("reset_possible")) and not overridden,
        reason_code=verdict.code or str(first.get("code", "")),
        reason=verdict.reason or "; ".join(str(r.get("message", "")) for r in reasons),
        zone_id=str(first["zone_id"]) if first.get("zone_id") else None,
        seq=verdict.seq, age_ms=age, counter=counter, mono=now, wall=wall, faults=faults,
        cameras={c: (not overridden and c not in sources) for c in cameras},
        cell=str(body.get("cell", "")), instance=str(body.get("instance", "")),
        zone_hash=str(body.get("config_hash", "")),
        zone_sets=_zone_sets(cmd))


def _zone_sets(command: dict | None) -> tuple[str, ...]:
    sets = (command or {}).get("zone_sets")
    return tuple(str(s) for s in sets) if isinstance(sets, list) else ()
