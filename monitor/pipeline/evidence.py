"""The cell decision's evidence: every camera's newest answer merged towards danger, the holds
handed over by the cell's other monitors, the zone sets and mutes in force, the STOP of a zone
swap until every camera has a frame on the new zones, and the oldest camera's frame time (a
camera that falls behind or stops makes the cell STOP). ``policy_inputs`` gathers them into
the policy's ``PolicyInputs``; the policy itself decides."""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

from monitor.pipeline.data import CameraState
from monitor.pipeline.mutes import MuteDesk
from monitor.pipeline.zone_sets import ZoneSets
from monitor.policy import PolicyInputs, Reason, ResetRequest, frame_causes
from monitor.tracking.handover import HandedHolds
from monitor.types import Fault, ZoneReport
from monitor.zones import merge_towards_danger
from monitor.zones.check import apply_mutes

ZONES_APPLYING = "zones_applying"


@dataclass
class ZonesApplying:
    """After a zone swap: the cameras without a frame checked against the new zones yet, and
    whether a decision has seen the swap's STOP (at least one decision sees it)."""

    waiting: set[str] = field(default_factory=set)
    stop_unseen: bool = False
    note: str = ""

    def start(self, camera_ids: Iterable[str], note: str) -> None:
        """A zone swap: STOP until every camera of ``camera_ids`` has a frame on it."""
        self.waiting = set(camera_ids)
        self.stop_unseen = True
        self.note = note

    def fault(self) -> Fault | None:
        """The ``zones_applying`` STOP fault of this decision (None: the swap is done)."""
        if not (self.waiting or self.stop_unseen):
            return None
        waiting = ", ".join(sorted(self.waiting)) or "none"
        self.stop_unseen = False
        return Fault(ZONES_APPLYING, f"new zone set applied{self.note}: "
                     f"cameras without a frame on it yet: {waiting}", True, "zones")


def policy_inputs(cameras: Mapping[str, CameraState], now: float, *,
                  extra: tuple[Fault, ...], pose_time: float | None,
                  reset: ResetRequest | None, with_frame: bool, applying: ZonesApplying,
                  handover: HandedHolds | None, zone_sets: ZoneSets, mute_desk: MuteDesk,
                  zone_error: str | None, latch_nonce: Callable[[], str]) -> PolicyInputs:
    """The policy's evidence: every camera's newest answer, merged towards danger."""
    faults = list(extra)
    applying_fault = applying.fault()
    if applying_fault is not None:
        faults.append(applying_fault)
    reports, times, detector_error = [], [], None
    for cid, cam in cameras.items():
        faults.extend(cam.faults)
        detector_error = detector_error or cam.detector_error
        if cam.health is not None:
            lost = cam.health.check_lost(now, cam.frame_time)
            if lost is not None and cam.frame_time is not None:
                faults.append(lost)
        if cam.frame_time is None:
            if len(cameras) > 1:
                faults.append(Fault("camera_waiting", f"{cid}: no frame processed yet",
                                    True, cid))
            continue
        times.append((cam.frame_time, cid))
        if cam.report is not None:
            reports.append(cam.report)
    handed = handover.decide(c.tracker for c in cameras.values() if c.tracker) \
        if handover is not None else None
    reports += [handed] if handed is not None and with_frame else []
    report = functools.reduce(merge_towards_danger, reports) if reports else None
    report = zone_sets.filter(report, now, faults)
    # muted zones as the zone file says (docs/muting.md): on the merged answer at this
    # decision only, so a mute's end applies exactly at the first decision after it
    muted, notes = mute_desk.muted(now)
    muted_stops = suspended_stops(report, muted)
    report = apply_mutes(report, muted)
    # the oldest camera's frame: a camera that falls behind or stops makes the cell STOP
    oldest = min(times) if with_frame and times else (None, None)
    frame_time, frame_source = oldest
    return PolicyInputs(frame_time=frame_time, frame_source=frame_source,
                        zone_report=report if with_frame else None,
                        faults=tuple(faults), detector_error=detector_error,
                        pose_time=pose_time, zone_error=zone_error,
                        reset_request=reset, mutes=notes, latch_nonce=latch_nonce(),
                        muted_stops=muted_stops)


def suspended_stops(report: ZoneReport | None, muted: Mapping[str, float | None]
                    ) -> tuple[Reason, ...]:
    """The STOP causes the mutes suspend: a person (seen, or lost inside) in a muted zone
    that would STOP unmuted, from the merged answer before the mutes. They refuse a reset
    while they hold (docs/muting.md, "Resets while muted"); a camera's newest answer, so a
    timer tick between frames keeps them as the frame showed them."""
    if report is None or not muted:
        return ()
    hits = tuple(h for h in report.hits if h.zone_id in muted)
    # the muted zones' hits alone: separation is never muted and STOPs of its own
    return frame_causes(ZoneReport(hits=hits)).stops if hits else ()
