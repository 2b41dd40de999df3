"""One processing step per frame: detect, merge, zones and geometry, health, policy.

The same ``Pipeline`` serves the live service and replay; only the clock differs (monotonic
seconds live, the video's own timestamps in replay), and it is always passed in, so replay is
deterministic. I/O (cameras, Zenoh, files) stays outside: the caller hands in frames, the newest
tool pose and reset requests, and publishes what comes out.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from monitor.detector import Detector
from monitor.health import CameraHealth, HealthReport
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
from monitor.types import Alert, Fault, FrameInfo, Persons, ZoneReport
from monitor.zones import Cell, check_persons


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


class Pipeline:
    """Frame in, command out. Holds the policy state and the per-camera health checker.

    ``cell`` may be None (no zones: persons never cause SLOW/STOP; say so to the user).
    """

    def __init__(self, detector: Detector, camera_id: str, policy: PolicyConfig,
                 cell: Cell | None = None, health: CameraHealth | None = None,
                 zone_error: str | None = None) -> None:
        self.detector = detector
        self.camera_id = camera_id
        self.policy = policy
        self.cell = cell
        self.prepared = cell.prepared if cell is not None else None
        self.health = health
        self.zone_error = zone_error
        self.state: PolicyState = initial_state()
        self.last_command: Command | None = None

    def process(self, image: np.ndarray, frame: FrameInfo, now: float,
                tool_pose=None, tool_speed_mps: float | None = None,
                pose_time: float | None = None, reset: ResetRequest | None = None,
                extra_faults: tuple[Fault, ...] = ()) -> StepResult:
        """Run every stage on one frame captured at ``frame.capture_time``; decide at ``now``."""
        stage: dict[str, float] = {}
        faults: list[Fault] = list(extra_faults)
        detector_error = None
        persons = Persons.empty(frame)
        t0 = time.perf_counter()
        try:
            detection = self.detector.detect_timed(image, frame)
            persons = detection.persons
            stage.update(preprocess=detection.preprocess_ms, inference=detection.inference_ms,
                         decode=detection.decode_ms)
            if detection.overflow:
                faults.append(Fault("detector_overflow", f"{detection.candidates} candidates "
                                    f"exceed top-k {self.detector.config.top_k}", True,
                                    "detector"))
        except Exception as exc:  # any failure of the detector is a STOP, never a crash or RUN
            detector_error = _one_line(exc)
        t1 = time.perf_counter()
        report = None
        if self.prepared is not None and detector_error is None:
            try:
                report = check_persons(
                    self.prepared, self.camera_id, persons.boxes_px, tool_pose, tool_speed_mps,
                    self.detector.foot_uncertainty_px(frame.width, frame.height))
            except Exception as exc:  # the zone answer is unknown: fail towards STOP
                faults.append(Fault("zone_check_error", _one_line(exc), True, "zones"))
        elif detector_error is None:
            report = ZoneReport()
        t2 = time.perf_counter()
        health = None
        if self.health is not None:
            try:
                health = self.health.check(image, now, persons.boxes_px)
                faults.extend(health.faults)
            except Exception as exc:  # health unknown: fail towards STOP
                faults.append(Fault("health_check_error", _one_line(exc), True, self.camera_id))
        t3 = time.perf_counter()
        inputs = PolicyInputs(frame_time=frame.capture_time, zone_report=report,
                              faults=tuple(faults), detector_error=detector_error,
                              pose_time=pose_time, zone_error=self.zone_error,
                              reset_request=reset)
        command = self._decide(inputs, now)
        t4 = time.perf_counter()
        stage.update(detect=(t1 - t0) * 1e3, zones=(t2 - t1) * 1e3, health=(t3 - t2) * 1e3,
                     policy=(t4 - t3) * 1e3)
        return StepResult(now, command, self._changed(command), frame, persons, report, health,
                          tuple(faults), health.alerts if health else (), stage)

    def tick(self, now: float, pose_time: float | None = None,
             reset: ResetRequest | None = None, extra_faults: tuple[Fault, ...] = ()) -> StepResult:
        """Evaluate timers with no new frame (frame timeout, clear time, resets, camera lost)."""
        faults = list(extra_faults)
        if self.health is not None:
            lost = self.health.check_lost(now)
            if lost is not None:
                faults.append(lost)
        inputs = PolicyInputs(frame_time=None, faults=tuple(faults), pose_time=pose_time,
                              zone_error=self.zone_error, reset_request=reset)
        command = self._decide(inputs, now)
        return StepResult(now, command, self._changed(command), faults=tuple(faults))

    def _decide(self, inputs: PolicyInputs, now: float) -> Command:
        self.state, command = step(self.state, inputs, now, self.policy)
        return command

    def _changed(self, command: Command) -> bool:
        changed = not command.same_as(self.last_command) or command.reset is not None
        self.last_command = command
        return changed

    @property
    def stopped(self) -> bool:
        return self.last_command is None or self.last_command.state == STOP
