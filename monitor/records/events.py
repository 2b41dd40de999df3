"""The command and alert records of ``events.jsonl``, shared by the replay
(``monitor.replay.video``), the incident recorder (``monitor.incidents.recorder``) and anyone who
reads them back.

One place for the record's shape, below all of its writers: the recorder takes the same
records as the replay without importing the replay. No wall-clock values: the same input gives
byte-identical events. ``describe`` is the one honest line for a command (times in seconds of
the video; the live incident recorder passes the wall clock) that the annotated video, the
events and the incident records all show.
"""

from __future__ import annotations

import math

from monitor.pipeline import StepResult
from monitor.timetext import TimeText, video_time
from monitor.types import Alert


def _r(value: float) -> float:
    return round(float(value), 4)


def _rounded(value):
    if isinstance(value, float):
        return _r(value) if math.isfinite(value) else str(value)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_rounded(v) for v in value]
    return value


def describe(command, when: TimeText = video_time) -> str:
    """One honest line for a command: ``Command.describe()`` where the policy has it, its
    times written by ``when`` (seconds of the video by default)."""
    text = getattr(command, "describe", None)
    if text is not None:
        return text(when)
    line = f"{command.state} x{command.speed_scale:.2f}"
    if command.latched:
        line += " LATCHED - reset needed"
    causes = [r.message for r in command.reasons if r.code != "latched"]
    return line + (f": {causes[0]}" if causes else "")


def command_event(result: StepResult, index: int, tick: bool = False,
                  when: TimeText = video_time) -> dict:
    """A command change as it goes into events.jsonl (no wall-clock values: deterministic;
    ``when`` writes the times of its ``describe``, the live recorder's are wall clock)."""
    cmd = result.command.to_dict()
    reasons = [{k: (_r(v) if isinstance(v, float) else v) for k, v in r.items()}
               for r in cmd["reasons"]]
    event = {"type": "command", "frame": index, "time_s": _r(result.now), "state": cmd["state"],
             "speed_scale": _r(cmd["speed_scale"]), "latched": cmd["latched"],
             "reasons": reasons}
    if tick:
        event["tick"] = True  # decided between two frames (timers), not on a frame
    for key in ("latched_by", "reset_possible", "clear_for_s"):  # the policy's honest view
        if key in cmd:
            event[key] = _rounded(cmd[key])
    if "reset" in cmd:
        event["reset"] = cmd["reset"]
    if "zone_sets" in cmd:  # the zone sets in force (docs/cases.md)
        event["zone_sets"] = cmd["zone_sets"]
    event["describe"] = describe(result.command, when)
    return event


def alert_event(alert: Alert, index: int, snapshot: str | None) -> dict:
    event = {"type": "alert", "frame": index, "time_s": _r(alert.time), "kind": alert.kind,
             "severity": alert.severity, "source": alert.source, "message": alert.message}
    if alert.details:  # what the bus's alert carries too: the operator, the fault, the zone
        event["details"] = _rounded(alert.details)
    if snapshot:
        event["snapshot"] = snapshot
    return event
