"""Evidence -> named causes: the first half of a policy step (pure).

Every check is written so that NaN, infinity or a missing value falls on the STOP side:
``not (age <= limit)`` rather than ``age > limit``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from monitor.policy.model import PolicyConfig, PolicyInputs, Reason
from monitor.types import Fault, ZoneHit, ZoneReport

# codes of the zone (per-frame) STOP causes; the rest are fail-safe causes of the step itself
ZONE_STOP_CODES = frozenset({"protective_zone", "person_lost", "separation"})


@dataclass(frozen=True)
class FrameCauses:
    """What one frame's zone report asks for: STOP causes, SLOW causes and the speed scale
    its SLOW causes allow (1.0 when there is none)."""

    stops: tuple[Reason, ...] = ()
    slows: tuple[Reason, ...] = ()
    scale: float = 1.0


def _person(hit: ZoneHit) -> int | str:
    """The cell person's id (one per person on every camera: monitor.tracking.cell_persons), else
    the tracked person's id (stable across frames), else the row."""
    if hit.who is not None:
        return hit.who
    return hit.track_id if hit.track_id is not None else hit.person


def _order(hit: ZoneHit) -> tuple:
    """A stable order (zone, person): the same causes in another order are no change to
    announce. Numbers before camera-qualified ids ("cam1:4"), which never compare with them."""
    who = _person(hit)
    return (hit.zone_id, (0, who, "") if isinstance(who, int) else (1, 0, str(who)), hit.lost)


def _hit_reason(hit: ZoneHit, stop: bool) -> Reason:
    who = _person(hit)
    if hit.lost:
        # the time stays a number (``since``): the edges write it in the operator's clock
        return Reason("person_lost" if stop else "warning_zone",
                      hit.note or f"person {who} lost inside {hit.zone_id}",
                      zone_id=hit.zone_id, person=who, distance_m=hit.distance_m,
                      since=hit.lost_since)
    return Reason("protective_zone" if stop else "warning_zone", f"person {who} in {hit.zone_id}",
                  zone_id=hit.zone_id, person=who, distance_m=hit.distance_m)


def frame_causes(report: ZoneReport | None) -> FrameCauses:
    """The causes one frame's zone report shows (None: zones not evaluated, nothing shown)."""
    if report is None:
        return FrameCauses()
    stops: list[Reason] = []
    slows: list[Reason] = []
    scale = 1.0
    for hit in sorted(report.hits, key=_order):
        # a warning zone whose scale is 0 (or NaN) allows no motion: it is a STOP
        stop = hit.kind == "protective" or not hit.speed_scale > 0.0
        reasons = stops if stop else slows
        reason = _hit_reason(hit, stop)
        # one person seen by two cameras in one zone is one cause (both hits still count)
        if not any(r.key() == reason.key() for r in reasons):
            reasons.append(reason)
        if not stop:
            scale = min(scale, hit.speed_scale)
    sep, req = report.tool_separation_m, report.required_separation_m
    # no person near the tool gives no separation: nothing to compare (the zone check says so)
    if sep is not None and req is not None and (
            not (math.isfinite(sep) and math.isfinite(req)) or sep < req):
        stops.append(Reason("separation", f"separation {sep:.3f} m < required {req:.3f} m",
                            distance_m=sep, required_m=req))
    v = report.separation_speed_scale
    if v is not None:
        if not v > 0.0:  # 0, negative or NaN: v_max allows no motion
            stops.append(Reason("separation", f"separation speed scale {v:.2f}: "
                                "no robot speed is safe at this separation",
                                distance_m=sep, required_m=req))
        elif v < 1.0:
            slows.append(Reason("separation_speed", f"separation allows {v:.2f} of the "
                                "programmed speed", distance_m=sep, required_m=req))
            scale = min(scale, v)
    return FrameCauses(tuple(stops), tuple(slows), scale)  # never above the 1.0 start


def _older_than(now: float, then: float, limit: float) -> bool:
    """True unless ``then`` is a finite time at most ``limit`` before ``now`` (NaN -> True)."""
    return not (abs(now - then) <= limit)


def fail_safe_causes(inputs: PolicyInputs, now: float, config: PolicyConfig,
                     prev_frame: float | None, has_frame: bool) -> tuple[Reason, ...]:
    """STOP causes of this step that do not come from a zone report: start-up, silence,
    staleness, errors and STOP faults. ``prev_frame``: ``now`` of the last earlier step with
    a frame."""
    causes: list[Reason] = []
    if prev_frame is None:  # this step's frame (if any) is the first: start-up STOP holds
        causes.append(Reason("startup", "first frame: watching the cell for clear_time"
                             if has_frame else "no frame processed yet"))
    elif not has_frame and _older_than(now, prev_frame, config.frame_timeout):
        causes.append(Reason("frame_timeout", f"no frame for {now - prev_frame:.3f} s "
                             f"(> {config.frame_timeout} s)"))
    if has_frame and _older_than(now, inputs.frame_time, config.max_frame_age):
        of = f"{inputs.frame_source}: " if inputs.frame_source else ""
        causes.append(Reason("frame_stale", f"{of}frame is {now - inputs.frame_time:.3f} s old "
                             f"(> {config.max_frame_age} s)", source=inputs.frame_source))
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
        elif _older_than(now, inputs.pose_time, config.pose_timeout):
            causes.append(Reason("pose_stale", f"tool pose is {now - inputs.pose_time:.3f} s "
                                 f"old (> {config.pose_timeout} s)", fault="pose_stale",
                                 source="pose"))
    causes.extend(fault_reason(f) for f in inputs.faults if stops(f))
    return tuple(causes)


# Faults that only say the monitor has not started watching yet (a camera of several that has
# not delivered its first frame): a STOP like the start-up one, and like it never latched by
# the manual interlock (unless ``startup_requires_reset``), so a restart of a multi-camera cell
# never waits for an operator. A latching fault (``Fault.latch``) still latches.
# A signed zone apply (monitor.service.zone_swap) is a start on new zones: the same STOP, not
# latched.
STARTUP_FAULTS = frozenset({"camera_waiting", "zones_applying"})


def is_startup(reason: Reason) -> bool:
    """The start-up STOP or a camera still waiting for its first frame."""
    return reason.code == "startup" or (reason.code == "fault" and reason.fault in STARTUP_FAULTS)


def stops(fault: Fault) -> bool:
    """A latching fault is a STOP fault even if it forgot to say so."""
    return fault.stop or fault.latch


def fault_reason(fault: Fault) -> Reason:
    return Reason("fault", f"{fault.name}: {fault.reason}", fault=fault.name,
                  source=fault.source or None)
