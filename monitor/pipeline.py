"""One processing step per frame: detect, merge, zones and geometry, health, policy.

Persons are tracked per camera (``monitor.tracks``): a person lost inside a protective or
warning zone keeps it occupied (``ZoneHit(lost=True)``) until seen again or until an operator's
``confirm_clear`` reset. Mask zones act on the detector's raw boxes before merging
(``monitor.zones.masks``), so a masked look-alike never swallows a real person.

The same ``Pipeline`` serves the live service and replay; only the clock differs (monotonic
seconds live, the video's own timestamps in replay), and it is always passed in, so replay is
deterministic. I/O (cameras, Zenoh, files) stays outside: the caller hands in frames, the newest
tool pose and reset requests, and publishes what comes out.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from monitor.cases import sets as cases
from monitor.cell_persons import CellPersons, CellPersonsConfig, Who
from monitor.detector import Detector
from monitor.handover import HandedHolds
from monitor.health import CameraHealth, HealthReport
from monitor.muting import Mute, MuteOutcome, MuteRequest, Mutes
from monitor.pipeline_cases import ZoneSets
from monitor.pipeline_mutes import MuteDesk
from monitor.policy import (
    STOP,
    Command,
    PolicyConfig,
    PolicyInputs,
    PolicyState,
    ResetRequest,
    initial_state,
    stale_latch,
    step,
)
from monitor.timetext import TimeText
from monitor.tracks import Hold, PersonTracker, TrackerConfig
from monitor.types import Alert, Fault, FrameInfo, Persons, ZoneReport
from monitor.zones import Cell, check_persons, merge_towards_danger
from monitor.zones.check import apply_mutes
from monitor.zones.masks import MaskRule
from monitor.zones.moving import ToolState

log = logging.getLogger(__name__)

# Faults that are expected at start-up or say nothing a person must act on.
# (zones_applying: the zones_applied alert already says it, with operator and hashes)
QUIET_FAULTS = frozenset({"camera_waiting", "zones_applying"})
ZONES_APPLYING = "zones_applying"


def _snapshot(image: np.ndarray | None, max_width: int = 1280) -> bytes | None:
    """A JPEG of the frame (scaled to at most ``max_width``), or None."""
    if image is None or image.ndim != 3:
        return None
    if image.shape[1] > max_width:
        scale = max_width / image.shape[1]
        image = cv2.resize(image, (max_width, round(image.shape[0] * scale)),
                           interpolation=cv2.INTER_AREA)
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
    return jpeg.tobytes() if ok else None


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text.splitlines()[0]}" if text else type(exc).__name__


@dataclass(frozen=True)
class StepResult:
    """What one processed frame (or one timer tick) produced."""

    now: float
    command: Command
    changed: bool  # the command differs from the previous step's (state, latch or reasons)
    frame: FrameInfo | None = None
    persons: Persons | None = None
    zone_report: ZoneReport | None = None
    health: HealthReport | None = None
    faults: tuple[Fault, ...] = ()
    alerts: tuple[Alert, ...] = ()
    stage_ms: dict[str, float] = field(default_factory=dict)  # stage -> wall ms (not replayed)
    track_ids: tuple[int, ...] = ()  # persistent person id per row of ``persons``
    masked_boxes: int = 0  # raw detector boxes suppressed by mask zones in this frame
    # mute requests judged since the previous step (the bus answers them), and the mutes
    # that hold at this decision (docs/muting.md)
    mute_outcomes: tuple[MuteOutcome, ...] = ()
    mutes: tuple[Mute, ...] = ()
    person_ids: tuple[Who, ...] = ()  # the cell person of each row (monitor.cell_persons)


@dataclass
class _MaskTally:
    """What one frame's mask rule did: raw boxes dropped, and the whole boxes of groups that
    touched a mask (``MaskCheck.touching``)."""

    masked: int = 0
    touching: list[np.ndarray] = field(default_factory=list)


def _with_touching(persons: Persons, touching: list[np.ndarray]) -> Persons:
    """``persons`` plus the whole box of every person who touched a masked object.

    The mask rule drops such a person's boxes inside the mask, so their merged box is only the
    part outside it: narrower than the person and placed up to a grid cell wrong. The whole
    group's box (person and object) is checked too, and the zone answer is the worse of the
    two: a box including the object is at worst a false STOP, never a missed one. Each extra
    box gets the best score of the person boxes it overlaps (the person's own)."""
    if not touching:
        return persons
    boxes = persons.boxes_px.astype(np.float64)
    extra_boxes, extra_scores = [], []
    for t in touching:
        if len(boxes) and (np.abs(boxes - t).max(axis=1) <= 1.0).any():
            continue  # merging already gave this box
        overlap = ((np.minimum(boxes[:, 2], t[2]) > np.maximum(boxes[:, 0], t[0]))
                   & (np.minimum(boxes[:, 3], t[3]) > np.maximum(boxes[:, 1], t[1])))
        score = float(persons.scores[overlap].max()) if overlap.any() else \
            float(persons.scores.max()) if len(persons) else 1.0
        extra_boxes.append(t)
        extra_scores.append(score)
    if not extra_boxes:
        return persons
    return Persons(np.concatenate([persons.boxes_px, np.array(extra_boxes, np.float32)]),
                   np.concatenate([persons.scores, np.array(extra_scores, np.float32)]),
                   persons.frame)


@dataclass
class _Camera:
    """What the pipeline remembers of one camera between steps."""

    health: CameraHealth | None = None
    frame_time: float | None = None  # capture time of its newest processed frame
    report: ZoneReport | None = None  # zone answer of that frame (None: unknown)
    faults: tuple[Fault, ...] = ()  # faults of that frame (health, detector, zones)
    detector_error: str | None = None
    tracker: PersonTracker | None = None


class Pipeline:
    """Frames in, command out. Holds the policy state and, per camera, its health checker and
    its newest zone answer.

    With several cameras, every decision uses the newest answer of *each* camera, merged
    towards danger (a person one camera sees in a zone keeps the STOP while another camera's
    frames come in), and the *oldest* of their frames is the one whose age the policy checks:
    a camera that stops delivering makes the whole cell STOP, and a camera that has not yet
    delivered a frame keeps it in STOP.

    ``cell`` may be None (no zones: persons never cause SLOW/STOP; say so to the user).
    """

    def __init__(self, detector: Detector, camera_id: str | Sequence[str], policy: PolicyConfig,
                 cell: Cell | None = None,
                 health: CameraHealth | Mapping[str, CameraHealth] | None = None,
                 zone_error: str | None = None, tracking: TrackerConfig | None = None,
                 linking: CellPersonsConfig | None = None) -> None:
        ids = (camera_id,) if isinstance(camera_id, str) else tuple(camera_id)
        if not ids:
            raise ValueError("a pipeline needs at least one camera")
        self.detector = detector
        self.camera_ids = ids
        self.camera_id = ids[0]
        self.policy = policy
        self.cell = cell
        self.prepared = cell.prepared if cell is not None else None
        if isinstance(health, CameraHealth):
            health = {ids[0]: health}
        self.cameras = {cid: _Camera((health or {}).get(cid), tracker=PersonTracker(
            tracking, self._to_floor(cid))) for cid in ids}
        self.persons = CellPersons(ids, linking or CellPersonsConfig())  # one id per person
        self._mask_rules: dict[tuple[str, int, int], MaskRule] = {}
        self.zone_error = zone_error
        self._active_faults: dict[tuple[str, str], Fault] = {}  # (name, source) -> fault
        self.state: PolicyState = initial_state()
        self.last_command: Command | None = None
        # serial -> nonce of a new latch (live: ``monitor.resets.LatchNonces`` of the bus's
        # boot); None: ``latch-<serial>``, deterministic for replay
        self.latch_nonces: Callable[[int], str] | None = None
        # zones muted by operators (``request_mutes``), applied at each decision; zone sets
        # (monitor/cases/), None without ``sets`` in the zone file
        self.mute_desk = MuteDesk(cell)
        self.zone_sets = ZoneSets(cell)
        self.handover: HandedHolds | None = None  # holds taken from the cell's other monitors

        # after a zone swap: cameras without a frame checked against the new zones yet, and
        # whether a decision has seen the swap's STOP (``swap_cell``)
        self.zones_waiting: set[str] = set()
        self._zones_stop_unseen = False
        self._zones_note = ""

    def request_mutes(self, requests: Sequence[MuteRequest], now: float
                      ) -> tuple[MuteOutcome, ...]:
        """Judge mute requests at ``now`` (before this step's decision): accepted ones hold
        from ``now`` for their duration. The outcomes and their alerts ride on the next
        ``StepResult``."""
        return self.mute_desk.request(requests, now)

    def take_case_events(self, events: Sequence[cases.Selection | cases.Refusal],
                         now: float) -> None:
        """Zone set selections (verified) and refused requests received since the last step;
        the next decision uses them. Without sets in the zone file they are ignored
        (none are received then: without sets every zone applies, the most protection)."""
        self.zone_sets.take_events(events, now)

    @property
    def mutes(self) -> Mutes:
        """The mute state (``monitor.muting.Mutes``)."""
        return self.mute_desk.mutes

    @mutes.setter
    def mutes(self, mutes: Mutes) -> None:
        self.mute_desk.mutes = mutes

    @property
    def when(self) -> TimeText:
        """Times in mute reasons (live: the wall clock)."""
        return self.mute_desk.when

    @when.setter
    def when(self, when: TimeText) -> None:
        self.mute_desk.when = when

    @property
    def case_plan(self) -> cases.CasePlan | None:
        return self.zone_sets.plan

    @property
    def case_state(self) -> cases.CaseState | None:
        return self.zone_sets.state

    @property
    def zones_in_force(self) -> cases.ZonesInForce | None:
        return self.zone_sets.in_force

    def swap_cell(self, cell: Cell, prepared=None,
                  health: Mapping[str, CameraHealth | None] | None = None,
                  note: str = "") -> None:
        """Decide with ``cell`` from the next step on (a signed zone apply, monitor.zone_swap).

        Everything derived from the zone set is replaced here: the prepared zones (with the
        reaction time of separation monitoring when given), the mask rules, each tracker's
        floor mapping, and the health checkers of cameras whose watch zones changed
        (``health``). The cell is then in STOP (``zones_applying``) until every camera has a
        frame checked against the new zones, and at least for one decision, so the policy's
        clear_time runs on the new zones before RUN; no decision mixes the two zone sets with
        RUN. Holds of lost persons are kept (their zones may be gone: still a STOP)."""
        self.cell = cell
        self.prepared = prepared if prepared is not None else cell.prepared
        self._mask_rules = {}
        for cid, cam in self.cameras.items():
            if cam.tracker is not None:
                cam.tracker.to_floor = self._to_floor(cid)
            if health is not None and cid in health:
                cam.health = health[cid]
        self.zones_waiting = set(self.camera_ids)
        self._zones_stop_unseen = True
        self._zones_note = note
        # muting and zone sets follow the new file: every mute ends at the next decision (its
        # zone is protective again; re-mute under the new rules), the sets start again from
        # the new default
        self.mute_desk.end_all(cell, "zones applied")
        self.zone_sets.restart(cell)

    def _to_floor(self, camera_id: str):
        model = self.cell.camera_models.get(camera_id) if self.cell is not None else None
        return model.pixel_to_floor if model is not None else None

    def _zones_of(self, frame: FrameInfo, tool_pose, tool_speed_mps,
                  tool_state: ToolState | None = None):
        """The zone check for other boxes of this frame's camera (a lost person's path)."""
        if self.prepared is None:
            return None
        foot = self.detector.foot_uncertainty_px(frame.width, frame.height)

        def zones_of(boxes_px: np.ndarray) -> ZoneReport:
            return check_persons(self.prepared, frame.camera_id, boxes_px, tool_pose,
                                 tool_speed_mps, foot, tool_state=tool_state)
        return zones_of

    def _tool(self, now: float, tool_pose, tool_speed_mps: float | None,
              pose_time: float | None) -> tuple[object, ToolState]:
        """The pose the separation uses (only with separation monitoring on: a pose fed for
        zones that follow the tool must not switch it on) and the tool state the following
        zones use (the pose with its age against ``policy.pose_timeout``)."""
        state = ToolState.at(now, tool_pose, pose_time, self.policy.pose_timeout,
                             tool_speed_mps)
        return (tool_pose if self.policy.separation_monitoring else None), state

    def mask_rule(self, frame: FrameInfo) -> MaskRule | None:
        """The mask rule of the frame's camera at its size (None: no mask zones)."""
        if self.cell is None:
            return None
        key = (frame.camera_id, frame.width, frame.height)
        if key not in self._mask_rules:
            margin = self.detector.foot_uncertainty_px(frame.width, frame.height)
            self._mask_rules[key] = MaskRule.for_camera(self.cell, frame.camera_id, frame.width,
                                                        frame.height, margin)
        rule = self._mask_rules[key]
        return rule if rule.active else None

    @property
    def holds(self) -> dict[str, tuple[Hold, ...]]:
        """Per camera, the lost persons keeping zones occupied (named as cell persons)."""
        return {cid: tuple(self.persons.hold(cid, h) for h in cam.tracker.holds)
                for cid, cam in self.cameras.items() if cam.tracker}

    @property
    def health(self) -> CameraHealth | None:
        """The first camera's health checker (single-camera use)."""
        return self.cameras[self.camera_id].health

    def _camera(self, frame: FrameInfo) -> _Camera:
        cam = self.cameras.get(frame.camera_id)
        if cam is None:
            raise ValueError(f"frame of unknown camera {frame.camera_id!r} "
                             f"(known: {', '.join(self.camera_ids)})")
        return cam

    def _pre_merge(self, frame: FrameInfo, tally: _MaskTally):
        """The camera's mask rule as the detector's pre-merge filter (None: no masks); counts
        the raw boxes it drops and keeps the whole boxes of groups touching a mask in
        ``tally``."""
        rule = self.mask_rule(frame)
        if rule is None:
            return None

        def pre_merge(boxes: np.ndarray) -> np.ndarray:
            check = rule.check(boxes)
            tally.masked += int(len(check.keep) - check.keep.sum())
            tally.touching.extend(check.touching)
            return check.keep

        return pre_merge

    def process(self, image: np.ndarray, frame: FrameInfo, now: float,
                tool_pose=None, tool_speed_mps: float | None = None,
                pose_time: float | None = None, reset: ResetRequest | None = None,
                extra_faults: tuple[Fault, ...] = ()) -> StepResult:
        """Run every stage on one frame captured at ``frame.capture_time``; decide at ``now``."""
        self._camera(frame)
        tally = _MaskTally()
        t0 = time.perf_counter()
        detection, detector_error = None, None
        try:  # the mask rule inside: a mask that cannot be applied is a detector error too
            detection = self.detector.detect_timed(image, frame,
                                                   pre_merge=self._pre_merge(frame, tally))
        except Exception as exc:  # any failure of the detector is a STOP, never a crash or RUN
            detector_error = _one_line(exc)
        return self._finish(image, frame, now, detection, detector_error, tally, t0,
                            tool_pose, tool_speed_mps, pose_time, reset, extra_faults)

    def process_batch(self, frames: Sequence[tuple[np.ndarray, FrameInfo]], now: float,
                      tool_pose=None, tool_speed_mps: float | None = None,
                      pose_time: float | None = None, reset: ResetRequest | None = None,
                      extra_faults: tuple[Fault, ...] = ()) -> list[StepResult]:
        """Frames of different cameras that are ready together: one inference for all of them
        (when the model has a dynamic batch; else one after the other), then each camera's
        zones, tracks and health and a decision per frame, exactly as ``process`` in turn would
        give. The reset (if any) is judged at the last decision, after every camera's answer."""
        if len(frames) == 1:
            image, frame = frames[0]
            return [self.process(image, frame, now, tool_pose, tool_speed_mps, pose_time, reset,
                                 extra_faults)]
        for _, frame in frames:
            self._camera(frame)
        tallies = [_MaskTally() for _ in frames]
        t0 = time.perf_counter()
        try:
            detections: list = self.detector.detect_batch_timed(
                [im for im, _ in frames], [fr for _, fr in frames],
                [self._pre_merge(fr, m) for (_, fr), m in zip(frames, tallies, strict=True)])
            errors: list[str | None] = [None] * len(frames)
        except Exception as exc:  # the whole batch failed: every frame is a detector error
            detections, errors = [None] * len(frames), [_one_line(exc)] * len(frames)
        results = []
        for i, ((image, frame), detection, error) in enumerate(
                zip(frames, detections, errors, strict=True)):
            last = i == len(frames) - 1
            results.append(self._finish(image, frame, now, detection, error, tallies[i], t0,
                                        tool_pose, tool_speed_mps, pose_time,
                                        reset if last else None, extra_faults))
            t0 = time.perf_counter()  # the next frame's stages start here (inference shared)
        return results

    def _finish(self, image: np.ndarray, frame: FrameInfo, now: float, detection,
                detector_error: str | None, tally: _MaskTally, t0: float, tool_pose,
                tool_speed_mps: float | None, pose_time: float | None,
                reset: ResetRequest | None, extra_faults: tuple[Fault, ...]) -> StepResult:
        """Everything after detection for one frame: zones, tracks, health, decision."""
        cam = self._camera(frame)
        stage: dict[str, float] = {}
        faults: list[Fault] = []
        persons = Persons.empty(frame)
        if detection is not None:
            persons = _with_touching(detection.persons, tally.touching)
            stage.update(preprocess=detection.preprocess_ms, inference=detection.inference_ms,
                         decode=detection.decode_ms)
            if detection.overflow:
                faults.append(Fault("detector_overflow", f"{detection.candidates} candidates "
                                    f"exceed top-k {self.detector.config.top_k}", True,
                                    "detector"))
        t1 = time.perf_counter()
        report = None
        tool_pose, tool_state = self._tool(now, tool_pose, tool_speed_mps, pose_time)
        if self.prepared is not None and detector_error is None:
            try:
                report = check_persons(
                    self.prepared, frame.camera_id, persons.boxes_px, tool_pose, tool_speed_mps,
                    self.detector.foot_uncertainty_px(frame.width, frame.height),
                    tool_state=tool_state)
            except Exception as exc:  # the zone answer is unknown: fail towards STOP
                faults.append(Fault("zone_check_error", _one_line(exc), True, "zones"))
        elif detector_error is None:
            report = ZoneReport()
        track_ids: tuple[int, ...] = ()
        person_ids: tuple[Who, ...] = ()
        if detector_error is None and cam.tracker is not None:
            try:
                update = cam.tracker.update(persons, report, frame.capture_time,
                                            (frame.width, frame.height),
                                            self._zones_of(frame, tool_pose, tool_speed_mps,
                                                           tool_state))
                named = self.persons.name(frame.camera_id, cam.tracker, update,
                                          frame.capture_time)
                report, track_ids, person_ids = named.report, update.track_ids, named.person_ids
                for line in named.lines:  # holds begun, guesses (said once, holds stay)
                    log.info("%s: %s", frame.camera_id, line)
            except Exception as exc:  # tracks unknown: a lost person may be missing, STOP
                faults.append(Fault("tracking_error", _one_line(exc), True, frame.camera_id))
        t2 = time.perf_counter()
        health = None
        if cam.health is not None:
            try:
                health = cam.health.check(image, now, persons.boxes_px)
                faults.extend(health.faults)
            except Exception as exc:  # health unknown: fail towards STOP
                faults.append(Fault("health_check_error", _one_line(exc), True,
                                    frame.camera_id))
        t3 = time.perf_counter()
        self.zones_waiting.discard(frame.camera_id)  # this frame was checked on the new zones
        cam.frame_time, cam.report, cam.faults = frame.capture_time, report, tuple(faults)
        cam.detector_error = detector_error
        cleared = self._confirm_clear(reset, now)
        inputs = self._inputs(now, extra_faults, pose_time, reset, with_frame=True)
        command = self._decide(inputs, now)
        outcomes, mute_alerts = self.mute_desk.take_events()
        alerts = (*cleared, *mute_alerts, *(health.alerts if health else ()),
                  *self._fault_alerts(inputs.faults, detector_error, now, image))
        t4 = time.perf_counter()
        stage.update(detect=(t1 - t0) * 1e3, zones=(t2 - t1) * 1e3, health=(t3 - t2) * 1e3,
                     policy=(t4 - t3) * 1e3)
        return StepResult(now, command, self._changed(command), frame, persons, cam.report,
                          health, inputs.faults, alerts, stage, track_ids, tally.masked,
                          outcomes, self.mute_desk.holding(now), person_ids)

    def tick(self, now: float, pose_time: float | None = None,
             reset: ResetRequest | None = None, extra_faults: tuple[Fault, ...] = ()) -> StepResult:
        """Evaluate timers with no new frame (frame timeout, clear time, resets, camera lost)."""
        cleared = self._confirm_clear(reset, now)
        inputs = self._inputs(now, extra_faults, pose_time, reset, with_frame=False)
        command = self._decide(inputs, now)
        detector_error = next((c.detector_error for c in self.cameras.values()
                               if c.detector_error), None)
        outcomes, mute_alerts = self.mute_desk.take_events()
        return StepResult(now, command, self._changed(command), faults=inputs.faults,
                          alerts=(*cleared, *mute_alerts,
                                  *self._fault_alerts(inputs.faults, detector_error, now, None)),
                          mute_outcomes=outcomes, mutes=self.mute_desk.holding(now))

    def _confirm_clear(self, reset: ResetRequest | None, now: float) -> tuple[Alert, ...]:
        """An operator looked and confirms the cell clear: drop every hold of a *lost* person
        (seen persons keep their hits), before the policy judges the reset as usual."""
        if reset is None or not reset.confirm_clear:
            return ()
        if stale_latch(reset, self.state.latched_by) is not None:
            return ()  # made for another latch: the policy refuses it; it may drop nothing
        dropped: list[tuple[str, Hold]] = []
        for cid, cam in self.cameras.items():
            if cam.tracker is None:
                continue
            dropped.extend((cid, self.persons.hold(cid, h)) for h in cam.tracker.drop_holds())
            if cam.report is not None:
                cam.report = replace(cam.report, hits=tuple(h for h in cam.report.hits
                                                            if not h.lost))
        handed = self.handover.drop() if self.handover is not None else ()
        what = "; ".join([*(f"{cid}: {h.describe()}" for cid, h in dropped),
                          *(h.describe() for h in handed)]) or "no lost persons held"
        message = f"operator {reset.operator} confirmed the cell clear: dropped {what}"
        log.warning(message)
        return (Alert("confirm_clear", "warning", message, "pipeline", now, details={
            "operator": reset.operator, "request_id": reset.request_id, "note": reset.note,
            "dropped": [{"camera": cid, "person": h.who, "track_id": h.track_id,
                         "lost_since": h.lost_since,
                         "zones": [z.zone_id for z in h.zones]} for cid, h in dropped]}),)

    def _fault_alerts(self, faults: tuple[Fault, ...], detector_error: str | None, now: float,
                      image: np.ndarray | None) -> tuple[Alert, ...]:
        """An alert when a STOP fault appears (with a snapshot when there is a frame) and one
        when it clears: a maintenance engineer learns that a camera went dark, not only the
        robot controller."""
        active = {(f.name, f.source): f for f in faults if f.stop and f.name not in QUIET_FAULTS}
        if detector_error:
            active[("detector_error", "detector")] = Fault("detector_error", detector_error,
                                                           True, "detector")
        alerts = []
        for key, fault in active.items():
            if key not in self._active_faults:
                alerts.append(Alert(fault.name, "critical", fault.reason, fault.source, now,
                                    snapshot_jpeg=_snapshot(image),
                                    details={"fault": fault.name, "stop": True}))
        for key, fault in self._active_faults.items():
            if key not in active:
                alerts.append(Alert(f"{fault.name}_cleared", "info",
                                    f"{fault.name} cleared: {fault.reason}", fault.source, now,
                                    details={"fault": fault.name}))
        self._active_faults = active
        return tuple(alerts)

    def _inputs(self, now: float, extra: tuple[Fault, ...], pose_time: float | None,
                reset: ResetRequest | None, with_frame: bool) -> PolicyInputs:
        """The policy's evidence: every camera's newest answer, merged towards danger."""
        faults = list(extra)
        if self.zones_waiting or self._zones_stop_unseen:
            waiting = ", ".join(sorted(self.zones_waiting)) or "none"
            faults.append(Fault(ZONES_APPLYING, f"new zone set applied{self._zones_note}: "
                                f"cameras without a frame on it yet: {waiting}", True, "zones"))
            self._zones_stop_unseen = False
        reports, times, detector_error = [], [], None
        for cid, cam in self.cameras.items():
            faults.extend(cam.faults)
            detector_error = detector_error or cam.detector_error
            if cam.health is not None:
                lost = cam.health.check_lost(now, cam.frame_time)
                if lost is not None and cam.frame_time is not None:
                    faults.append(lost)
            if cam.frame_time is None:
                if len(self.cameras) > 1:
                    faults.append(Fault("camera_waiting", f"{cid}: no frame processed yet",
                                        True, cid))
                continue
            times.append((cam.frame_time, cid))
            if cam.report is not None:
                reports.append(cam.report)
        handed = self.handover.decide(c.tracker for c in self.cameras.values() if c.tracker) \
            if self.handover is not None else None
        reports += [handed] if handed is not None and with_frame else []
        report = functools.reduce(merge_towards_danger, reports) if reports else None
        report = self.zone_sets.filter(report, now, faults)
        # muted zones as the zone file says (docs/muting.md): on the merged answer at this
        # decision only, so a mute's end applies exactly at the first decision after it
        muted, notes = self.mute_desk.muted(now)
        report = apply_mutes(report, muted)
        # the oldest camera's frame: a camera that falls behind or stops makes the cell STOP
        oldest = min(times) if with_frame and times else (None, None)
        frame_time, frame_source = oldest
        return PolicyInputs(frame_time=frame_time, frame_source=frame_source,
                            zone_report=report if with_frame else None,
                            faults=tuple(faults), detector_error=detector_error,
                            pose_time=pose_time, zone_error=self.zone_error,
                            reset_request=reset, mutes=notes,
                            latch_nonce=self.latch_nonces(self.state.latches + 1)
                            if self.latch_nonces is not None else "")

    def _decide(self, inputs: PolicyInputs, now: float) -> Command:
        self.state, command = step(self.state, inputs, now, self.policy)
        if self.zone_sets.in_force is not None:
            command = replace(command, zone_sets=self.zone_sets.in_force.sets)
        return command

    def _changed(self, command: Command) -> bool:
        changed = not command.same_as(self.last_command) or command.reset is not None
        self.last_command = command
        return changed

    @property
    def stopped(self) -> bool:
        return self.last_command is None or self.last_command.state == STOP
