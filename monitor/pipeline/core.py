"""One processing step per frame for one camera, and the decision handed on: detect (with the
mask rule on the raw boxes), zones, tracks, health, then the cell's decision over every
camera's newest answer.

The parts live beside this module: the mask rule (``masking``), the evidence merged across
cameras (``evidence``), holds and confirm-clear (``holds``), fault alerts (``fault_alerts``),
mutes (``mutes``) and zone sets (``zone_sets``); the policy itself is ``monitor.policy``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from monitor.cases import sets as cases
from monitor.cases.muting import MuteOutcome, MuteRequest, Mutes
from monitor.detector import Detector
from monitor.health import CameraHealth
from monitor.health.acceptance import judge_accept
from monitor.health.objects import carry_over, objects_of
from monitor.pipeline.data import CameraState, StepResult
from monitor.pipeline.evidence import ZonesApplying, policy_inputs
from monitor.pipeline.fault_alerts import FaultAlerts, one_line
from monitor.pipeline.holds import (
    area_views,
    confirm_clear,
    explain_refusal,
    holds_of,
    pocket_views,
    unseen_views,
)
from monitor.pipeline.locate import camera_working, free_elsewhere, hidden_of, locate
from monitor.pipeline.masking import MaskRules, MaskTally, with_touching
from monitor.pipeline.mutes import MuteDesk
from monitor.pipeline.zone_sets import ZoneSets
from monitor.policy import (
    STOP,
    Command,
    PolicyConfig,
    PolicyInputs,
    PolicyState,
    ResetRequest,
    initial_state,
    step,
)
from monitor.timetext import TimeText
from monitor.tracking.cell_persons import CellPersons, CellPersonsConfig
from monitor.tracking.handover import HandedHolds
from monitor.tracking.tracks import Hold, PersonTracker, TrackerConfig
from monitor.types import Alert, Fault, FrameInfo, Persons
from monitor.wire.object_accepts import AcceptOutcome, ObjectAccept, accept_command
from monitor.zones import Cell
from monitor.zones.masks import MaskRule
from monitor.zones.prepare import PreparedCell, with_references


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
                 linking: CellPersonsConfig | None = None,
                 references: Mapping[str, np.ndarray | None] | None = None) -> None:
        ids = (camera_id,) if isinstance(camera_id, str) else tuple(camera_id)
        if not ids:
            raise ValueError("a pipeline needs at least one camera")
        self.detector = detector
        self.camera_ids = ids
        self.camera_id = ids[0]
        self.policy = policy
        self.cell = cell
        # each camera's commissioning reference (BGR; None: none): its horizontal edges tell
        # a box cut off by a fixture, declared or not (monitor.geometry.edges)
        self.references = {cid: img for cid, img in (references or {}).items()
                           if img is not None}
        self.prepared = cell.prepared if cell is not None else None
        # objects put into the zones since commissioning, per camera with a reference
        # (monitor.health.objects); the cameras without one are named by ``no_reference``
        self.objects = objects_of(cell, self.references)
        # operators' acceptances of those objects judged since the last step: their outcomes
        # (the bus answers them) and alerts ride on the next StepResult
        self._accepts: list[tuple[AcceptOutcome, Alert]] = []
        # the visible share of a person the detector was measured to need
        # (monitor.detector.visible; None: the zone file's person.visible_fraction)
        self.visible_fraction: float | None = None
        if isinstance(health, CameraHealth):
            health = {ids[0]: health}
        self.cameras = {cid: CameraState((health or {}).get(cid), tracker=PersonTracker(
            tracking, self._to_floor(cid))) for cid in ids}
        self.persons = CellPersons(ids, linking or CellPersonsConfig())  # one id per person
        self.masks = MaskRules(cell, detector)
        self.zone_error = zone_error
        self.fault_alerts = FaultAlerts()  # STOP faults alerted when they appear and end
        self.state: PolicyState = initial_state()
        self.last_command: Command | None = None
        # serial -> nonce of a new latch (live: ``monitor.wire.resets.LatchNonces`` of the bus's
        # boot); None: ``latch-<serial>``, deterministic for replay
        self.latch_nonces: Callable[[int], str] | None = None
        # zones muted by operators (``request_mutes``), applied at each decision; zone sets
        # (monitor/cases/), None without ``sets`` in the zone file
        self.mute_desk = MuteDesk(cell)
        self.zone_sets = ZoneSets(cell)
        self.handover: HandedHolds | None = None  # holds taken from the cell's other monitors
        # per camera, what hides its pockets (``holds.pocket_views``: named once per pocket set)
        self._pocket_names: dict[str, tuple[object, list[tuple[str, ...]]]] = {}

        # after a zone swap: STOP until every camera has a frame on the new zones
        # (``swap_cell``)
        self.applying = ZonesApplying()

    @property
    def prepared(self) -> PreparedCell | None:
        """The prepared zones the zone check uses, with the references' edges."""
        return self._prepared

    @prepared.setter
    def prepared(self, prepared: PreparedCell | None) -> None:
        self._prepared = with_references(prepared, self.references) \
            if prepared is not None and self.references else prepared

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

    def accept_objects(self, requests: Sequence[ObjectAccept], now: float
                       ) -> tuple[AcceptOutcome, ...]:
        """Judge operators' acceptances of objects since commissioning at ``now`` (before
        this step's decision: an accepted object's fault is gone from it on). The outcomes
        and alerts also ride on the next ``StepResult``."""
        zones = [z.id for z in self.cell.zones if z.kind in ("protective", "warning")] \
            if self.cell is not None else []
        judged = [judge_accept(self.objects, self.camera_ids, zones, r, now) for r in requests]
        self._accepts.extend(judged)
        return tuple(o for o, _ in judged)

    def _take_accepts(self) -> tuple[tuple[AcceptOutcome, ...], tuple[Alert, ...]]:
        judged, self._accepts = self._accepts, []
        return tuple(o for o, _ in judged), tuple(a for _, a in judged)

    @property
    def mutes(self) -> Mutes:
        """The mute state (``monitor.cases.muting.Mutes``)."""
        return self.mute_desk.mutes

    @mutes.setter
    def mutes(self, mutes: Mutes) -> None:
        self.mute_desk.mutes = mutes

    @property
    def when(self) -> TimeText:
        """Times in mute reasons and the latch's reason (live: the wall clock)."""
        return self.mute_desk.when

    @when.setter
    def when(self, when: TimeText) -> None:
        self.mute_desk.when = when

    @property
    def zones_waiting(self) -> set[str]:
        """After a zone swap: the cameras without a frame checked against the new zones."""
        return self.applying.waiting

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
        """Decide with ``cell`` from the next step on (a signed zone apply,
        monitor.service.zone_swap).

        Everything derived from the zone set is replaced here: the prepared zones (with the
        reaction time of separation monitoring when given), the mask rules, each tracker's
        floor mapping, and the health checkers of cameras whose watch zones changed
        (``health``), the objects-since-commissioning watches (``carry_over``). The cell is
        then in STOP (``zones_applying``) until every camera has a
        frame checked against the new zones, and at least for one decision, so the policy's
        clear_time runs on the new zones before RUN; no decision mixes the two zone sets with
        RUN. Holds of lost persons are kept (their zones may be gone: still a STOP)."""
        self.cell = cell
        self._pocket_names.clear()  # the occluders that hide the pockets may be others now
        self.prepared = prepared if prepared is not None else cell.prepared
        self.masks = MaskRules(cell, self.detector)
        for cid, cam in self.cameras.items():
            if cam.tracker is not None:
                cam.tracker.to_floor = self._to_floor(cid)
            if health is not None and cid in health:
                cam.health = health[cid]
        self.applying.start(self.camera_ids, note)
        # muting and zone sets follow the new file: every mute ends at the next decision (its
        # zone is protective again; re-mute under the new rules), the sets start again from
        # the new default
        self.mute_desk.end_all(cell, "zones applied")
        self.zone_sets.restart(cell)
        # the objects since commissioning are judged against the new zones (a zone that is
        # protective now must hold for a crate already standing in it)
        objects = objects_of(cell, self.references)
        for cid, watch in objects.items():
            if cid in self.objects:
                carry_over(self.objects[cid], watch)
        self.objects = objects

    def _to_floor(self, camera_id: str):
        model = self.cell.camera_models.get(camera_id) if self.cell is not None else None
        return model.pixel_to_floor if model is not None else None

    def mask_rule(self, frame: FrameInfo) -> MaskRule | None:
        """The mask rule of the frame's camera at its size (None: no mask zones)."""
        return self.masks.rule(frame)

    @property
    def holds(self) -> dict[str, tuple[Hold, ...]]:
        """Per camera, the lost persons keeping zones occupied (named as cell persons)."""
        return holds_of(self.cameras, self.persons)

    @property
    def health(self) -> CameraHealth | None:
        """The first camera's health checker (single-camera use)."""
        return self.cameras[self.camera_id].health

    def _camera(self, frame: FrameInfo) -> CameraState:
        cam = self.cameras.get(frame.camera_id)
        if cam is None:
            raise ValueError(f"frame of unknown camera {frame.camera_id!r} "
                             f"(known: {', '.join(self.camera_ids)})")
        return cam

    def process(self, image: np.ndarray, frame: FrameInfo, now: float,
                tool_pose=None, tool_speed_mps: float | None = None,
                pose_time: float | None = None, reset: ResetRequest | None = None,
                extra_faults: tuple[Fault, ...] = ()) -> StepResult:
        """Run every stage on one frame captured at ``frame.capture_time``; decide at ``now``."""
        self._camera(frame)
        tally = MaskTally()
        t0 = time.perf_counter()
        detection, detector_error = None, None
        try:  # the mask rule inside: a mask that cannot be applied is a detector error too
            detection = self.detector.detect_timed(image, frame,
                                                   pre_merge=self.masks.pre_merge(frame, tally))
        except Exception as exc:  # any failure of the detector is a STOP, never a crash or RUN
            detector_error = one_line(exc)
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
        tallies = [MaskTally() for _ in frames]
        t0 = time.perf_counter()
        try:
            detections: list = self.detector.detect_batch_timed(
                [im for im, _ in frames], [fr for _, fr in frames],
                [self.masks.pre_merge(fr, m) for (_, fr), m in zip(frames, tallies, strict=True)])
            errors: list[str | None] = [None] * len(frames)
        except Exception as exc:  # the whole batch failed: every frame is a detector error
            detections, errors = [None] * len(frames), [one_line(exc)] * len(frames)
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
                detector_error: str | None, tally: MaskTally, t0: float, tool_pose,
                tool_speed_mps: float | None, pose_time: float | None,
                reset: ResetRequest | None, extra_faults: tuple[Fault, ...]) -> StepResult:
        """Everything after detection for one frame: zones and tracks (``locate``), health,
        the decision."""
        cam = self._camera(frame)
        stage: dict[str, float] = {}
        faults: list[Fault] = []
        persons = Persons.empty(frame)
        if detection is not None:
            persons = with_touching(detection.persons, tally.touching)
            stage.update(preprocess=detection.preprocess_ms, inference=detection.inference_ms,
                         decode=detection.decode_ms)
            if detection.overflow:
                faults.append(Fault("detector_overflow", f"{detection.candidates} candidates "
                                    f"exceed top-k {self.detector.config.top_k}", True,
                                    "detector"))
        t1 = time.perf_counter()
        # health first: a camera in fault sees nothing free for its lost persons' areas
        health = None
        if cam.health is not None:
            try:
                health = cam.health.check(image, now, persons.boxes_px)
                faults.extend(health.faults)
            except Exception as exc:  # health unknown: fail towards STOP
                faults.append(Fault("health_check_error", one_line(exc), True,
                                    frame.camera_id))
        working = camera_working(frame.camera_id, [*faults, *extra_faults])
        watch = self.objects.get(frame.camera_id)
        object_alerts: list[Alert] = []
        if watch is not None:  # what changed since commissioning (no person, lasting)
            try:
                # the health checks' analysis image of this frame: made once (issue 49)
                object_alerts = watch.check(image, persons.boxes_px, now, working,
                                            health.analysis_bgr if health else None)
                faults.extend(watch.faults())
            except Exception as exc:  # unknown: fail towards STOP
                faults.append(Fault("object_check_error", one_line(exc), True,
                                    frame.camera_id))
        t2 = time.perf_counter()
        # a repeated picture shows the cell as it was when it last really changed: its
        # persons were seen then (lost persons' times), and its age counts from then
        shown = frame
        if health is not None and not health.picture_changed and cam.frame_time is not None:
            shown = replace(frame, capture_time=min(cam.frame_time, frame.capture_time))
        report, track_ids, person_ids, gap_alerts = locate(
            shown, persons, cam, self.prepared, self.detector, self.persons, detector_error,
            now, tool_pose, tool_speed_mps, pose_time, self.policy, faults, working=working,
            hidden=hidden_of(self.cell, frame.camera_id, self.masks.rule(frame),
                             self.visible_fraction, watch),
            elsewhere=free_elsewhere(self.cameras, self.cell, frame.camera_id,
                                     frame.capture_time, self.policy.clear_time),
            image=image, reference=self.references.get(frame.camera_id))
        t3 = time.perf_counter()
        self.applying.waiting.discard(frame.camera_id)  # this frame was checked on the new zones
        cam.frame_time, cam.report, cam.faults = shown.capture_time, report, tuple(faults)
        cam.detector_error = detector_error
        cleared, dropped = self._confirm_clear(reset, now, extra_faults)
        inputs = self._inputs(now, extra_faults, pose_time, reset, with_frame=True,
                              lost_dropped=dropped)
        command = self._decide(inputs, now)
        outcomes, mute_alerts = self.mute_desk.take_events()
        accepts, accept_alerts = self._take_accepts()
        alerts = (*cleared, *mute_alerts, *accept_alerts, *(health.alerts if health else ()),
                  *object_alerts, *gap_alerts,
                  *self._fault_alerts(inputs.faults, detector_error, now, image))
        t4 = time.perf_counter()
        stage.update(detect=(t1 - t0) * 1e3, health=(t2 - t1) * 1e3, zones=(t3 - t2) * 1e3,
                     policy=(t4 - t3) * 1e3)
        return StepResult(now, command, self._changed(command), frame, persons, cam.report,
                          health, inputs.faults, alerts, stage, track_ids, tally.masked,
                          outcomes, self.mute_desk.holding(now), person_ids, accepts,
                          *self._screen())

    def tick(self, now: float, pose_time: float | None = None,
             reset: ResetRequest | None = None, extra_faults: tuple[Fault, ...] = ()) -> StepResult:
        """Evaluate timers with no new frame (frame timeout, clear time, resets, camera lost)."""
        cleared, dropped = self._confirm_clear(reset, now, extra_faults)
        inputs = self._inputs(now, extra_faults, pose_time, reset, with_frame=False,
                              lost_dropped=dropped)
        command = self._decide(inputs, now)
        detector_error = next((c.detector_error for c in self.cameras.values()
                               if c.detector_error), None)
        outcomes, mute_alerts = self.mute_desk.take_events()
        accepts, accept_alerts = self._take_accepts()
        areas, unseen, pockets = self._screen()
        return StepResult(now, command, self._changed(command), faults=inputs.faults,
                          alerts=(*cleared, *mute_alerts, *accept_alerts,
                                  *self._fault_alerts(inputs.faults, detector_error, now, None)),
                          mute_outcomes=outcomes, mutes=self.mute_desk.holding(now),
                          accept_outcomes=accepts,
                          areas=areas, unseen=unseen, pockets=pockets)

    def _screen(self) -> tuple[tuple, tuple, tuple]:
        """Why the cell is held, for the screen: the lost persons' areas, the unseen floor and
        the hidden pockets (copies, ``StepResult.areas``, ``.unseen``, ``.pockets``)."""
        pockets = pocket_views(self.cameras, self.cell, self._pocket_names)
        return (area_views(self.cameras, self.persons, self.cell, pockets),
                unseen_views(self.cameras), pockets)

    def _confirm_clear(self, reset: ResetRequest | None, now: float,
                       extra_faults: tuple[Fault, ...] = ()) -> tuple[tuple[Alert, ...], bool]:
        """An operator's confirm-clear reset drops every hold of a lost person
        (``holds.confirm_clear``; refused while a camera is in fault), before the policy
        judges the reset as usual, in the same step."""
        behind = self._behind_objects() if reset is not None and reset.confirm_clear else {}
        alerts, dropped = confirm_clear(reset, self.state.latched_by, self.cameras,
                                        self.persons, self.handover, now, extra_faults)
        if dropped:  # never accepts an object (that is its own request: accept_objects)
            # behind an object no operator has accepted, nobody has looked: a lost person
            # whose area reaches its shadow stays held until that is seen free (the object
            # moved, another camera). An accepted one is an occluder declared at run time:
            # looked at, like a fixture of the zone file, the confirm-clear releases it
            for cid, areas in behind.items():
                cam = self.cameras[cid]
                if cam.tracker is None:
                    continue
                cam.tracker.where.areas.update(areas)
                if cam.report is not None:
                    cam.report = replace(cam.report, hits=(*cam.report.hits,
                                                           *cam.tracker.held_hits()))
        # holds kept behind an object: the policy must judge this step with the carried
        # causes, not as if every lost person had been dropped (a reset between frames would
        # otherwise pass them by)
        return alerts, dropped and not any(behind.values())

    def _behind_objects(self) -> dict[str, dict]:
        """Per camera, the lost persons' areas that reach into the shadow of an object no
        operator has accepted."""
        out: dict[str, dict] = {}
        for cid, watch in self.objects.items():
            cam = self.cameras.get(cid)
            where = cam.tracker.where if cam is not None and cam.tracker is not None else None
            if where is None or where.grid is None or not watch.objects:
                continue
            grid = where.grid
            spec = self.cell.cameras[cid] if self.cell is not None else None
            scale = np.array([spec.width / grid.width, spec.height / grid.height]) \
                if spec is not None else np.ones(2)
            shadow = watch.hidden_cells(grid.centres() * scale, unaccepted_only=True
                                        ).reshape(grid.shape)
            kept = {tid: a for tid, a in where.areas.items() if (a.cells & shadow).any()}
            if kept:
                out[cid] = kept
        return out

    def _behind_objects_hint(self, command: Command) -> Command:
        """A reset refused while a lost person's area reaches behind an object nobody accepted
        says so: a confirm-clear keeps that hold (nobody looked behind it); accepted after
        looking, the object is a declared occluder and a confirm-clear releases it."""
        reset = command.reset
        if reset is None or reset.accepted or "lost" not in reset.message:
            return command
        behind = [(cid, o) for cid in self._behind_objects()
                  for o in self.objects[cid].objects.values() if o.accepted_by is None]
        if not behind:
            return command
        cid, obj = behind[0]
        hint = (f"; a lost person's area reaches behind the object in {obj.place()} on {cid} "
                "that nobody accepted: a confirm-clear keeps that hold until it is seen free; "
                f"look behind it, accept it ({accept_command(cid, obj.zone_ids[0])}), then "
                "confirm the cell clear")
        return replace(command, reset=replace(reset, message=reset.message + hint))

    def _fault_alerts(self, faults: tuple[Fault, ...], detector_error: str | None, now: float,
                      image: np.ndarray | None) -> tuple[Alert, ...]:
        return self.fault_alerts.alerts(faults, detector_error, now, image)

    def _inputs(self, now: float, extra: tuple[Fault, ...], pose_time: float | None,
                reset: ResetRequest | None, with_frame: bool, lost_dropped: bool = False
                ) -> PolicyInputs:
        """The policy's evidence: every camera's newest answer, merged towards danger."""
        return replace(policy_inputs(
            self.cameras, now, extra=extra, pose_time=pose_time, reset=reset,
            with_frame=with_frame, applying=self.applying, handover=self.handover,
            zone_sets=self.zone_sets, mute_desk=self.mute_desk, zone_error=self.zone_error,
            latch_nonce=lambda: self.latch_nonces(self.state.latches + 1)
            if self.latch_nonces is not None else ""), lost_dropped=lost_dropped)

    def _decide(self, inputs: PolicyInputs, now: float) -> Command:
        self.state, command = step(self.state, inputs, now, self.policy, self.when)
        # a refusal for a lost person says what ends that hold (docs/tracking.md)
        command = explain_refusal(command, self.cameras, self.persons, self.cell,
                                  self.policy.clear_time)
        command = self._behind_objects_hint(command)
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
