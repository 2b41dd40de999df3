"""The live loop's two ends in ``monitor run``: ``LiveFeed`` (frames from the grabbers, round
robin and bounded in wait, with the resets, mutes, pose and camera faults of each step) and
``ServiceSink`` (each step's command, detections, alerts, log lines, status and gauges)."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import statistics
import threading
import time
from collections import deque

from monitor.bus.session import SafetyBus
from monitor.detector.test_model import TEST_MODEL_REASON
from monitor.driver import Step, StepInputs
from monitor.health import LOST
from monitor.health.acceptance import changed_cell, changed_signature
from monitor.pipeline import StepResult
from monitor.pipeline.pocket_views import screen_body
from monitor.policy import Reason
from monitor.service.log import command_fields, event
from monitor.service.metrics import CameraFigures, Metrics
from monitor.timetext import wall_clock
from monitor.types import Alert, Fault
from monitor.zones.separation import tool_points_in_tracker


class LiveFeed:
    """Frames from the grabbers, round robin, on the monotonic clock. Each wait is bounded by
    ``tick_s / cameras``, so the policy's timers run without frames."""

    def __init__(self, grabbers: list, bus: SafetyBus, pose, tick_s: float,
                 stop: threading.Event, duration: float | None, alert, prepared=None,
                 max_fps: dict[str, float | None] | None = None) -> None:
        self.grabbers = grabbers
        # [camera] max_fps: a camera is taken at most this often (its frames in between wait
        # in the grabber, which keeps only the newest)
        self.min_interval = {cid: 1.0 / fps for cid, fps in (max_fps or {}).items() if fps}
        self.last_taken: dict[str, float] = {}
        self.use_zones(prepared)
        self.zones = None  # monitor.service.zone_swap.LiveZones: signed zone applies, between steps
        self.bus = bus
        self.pose = pose
        self.stop = stop
        self.alert = alert
        self.wait = tick_s / len(grabbers)
        self.end = time.monotonic() + duration if duration is not None else None
        self.turn = 0
        self.cases = None  # the zone set selections' receiver (None: no sets)
        self.handover = None  # monitor.bus.holds.HoldsLink: a silent peer is a STOP fault
        # None: never connected yet (start-up is no loss); True / False after that
        self.was_connected: dict[str, bool | None] = {g.camera_id: None for g in grabbers}

    def use_zones(self, prepared) -> None:
        """The tool points whose speed bounds the whole tool's (none without a tool)."""
        self.tool_points = tool_points_in_tracker(prepared) if prepared is not None else None
        self.unknown_speed = (prepared.separation.robot_speed_default_mps
                              if prepared is not None else 0.0)

    def next(self, idle: bool = False):
        """The next frame of the camera whose turn it is, or a tick (None) after waiting up to
        ``wait``; ``idle`` (a check is due): a tick at once when no frame is waiting."""
        if self.end is not None and time.monotonic() >= self.end:
            return None
        grabber = self.grabbers[self.turn % len(self.grabbers)]
        self.turn += 1
        if not self._due(grabber.camera_id):  # [camera] max_fps: this camera waits its turn
            if not idle:
                self.stop.wait(self.wait)
            return None, time.monotonic()
        frame = grabber.get(timeout=0.0 if idle else self.wait)
        if frame is not None:
            self.last_taken[grabber.camera_id] = time.monotonic()
        elif not grabber.alive:  # the source ended: get() no longer waits
            self.stop.wait(self.wait)
        return frame, time.monotonic()

    def next_batch(self, idle: bool = False):
        """Every camera's newest frame that is ready now (waiting, bounded, only for the camera
        whose turn it is; not at all when ``idle``): ``(frames, now)``, frames possibly empty
        (a timer tick)."""
        if self.end is not None and time.monotonic() >= self.end:
            return None
        n = len(self.grabbers)
        first = self.turn % n
        self.turn += 1
        frames, waited = [], False
        for k in range(n):
            grabber = self.grabbers[(first + k) % n]
            if not self._due(grabber.camera_id):
                continue
            frame = grabber.get(timeout=0.0 if waited or idle else self.wait)
            waited = True
            if frame is not None:
                frames.append(frame)
                self.last_taken[grabber.camera_id] = time.monotonic()
        if not frames and not idle and (not waited or not any(g.alive for g in self.grabbers)):
            # every camera throttled by max_fps, or every source ended (get() no longer waits)
            self.stop.wait(self.wait)
        return frames, time.monotonic()

    def _due(self, camera_id: str) -> bool:
        interval = self.min_interval.get(camera_id)
        last = self.last_taken.get(camera_id)
        return interval is None or last is None or time.monotonic() - last >= interval

    def inputs(self, now: float) -> StepInputs:
        if self.zones is not None:
            self.zones.poll(now)  # the loop's thread, before this step: the next decides on it
        resets = self.bus.poll_resets()
        case_events = self.cases.poll() if self.cases is not None else ()
        pose_time = tool_pose = tool_speed = None
        faults = list(self.camera_faults()) + list(self.bus.faults())  # e.g. duplicate_monitor
        if self.handover is not None:
            faults += self.handover.faults()
        if self.pose is not None:
            reading = self.pose.latest()
            if reading is not None:
                pose_time, tool_pose = reading.received, reading.tool_pose()
                # measured from the stream itself (every tool point, rotation included), the
                # larger of measured and reported; a lying velocity field is a STOP fault
                speed = reading.tool_speed(self.tool_points, unknown_mps=self.unknown_speed)
                tool_speed = speed.speed_mps
                if speed.fault is not None:
                    faults.append(speed.fault)
            for rejection in self.pose.drain_rejections():
                from monitor.wire.alerts import pose_alert

                self.alert(pose_alert(rejection, "pose", now))
        return StepInputs(reset=resets[-1] if resets else None,
                          extra_faults=tuple(faults), tool_pose=tool_pose,
                          tool_speed_mps=tool_speed, pose_time=pose_time,
                          mutes=self.bus.poll_mutes(), case_events=case_events,
                          accepts=self.bus.poll_accepts())

    def camera_faults(self) -> tuple[Fault, ...]:
        """A loss a grabber has seen (read/open error, wrong size, end of stream) is a STOP
        cause at once, with the camera's own error; frame_timeout is only the backstop."""
        faults = []
        for g in self.grabbers:
            connected, error = g.connected, g.last_error
            before = self.was_connected[g.camera_id]
            if connected and before is not True:
                event("camera connected" if before is None else "camera reconnected",
                      camera=g.camera_id)
                self.was_connected[g.camera_id] = True
            elif not connected and (before is True or (before is None and error)):
                event("camera lost" if before else "camera not available", logging.WARNING,
                      camera=g.camera_id, error=error)
                self.was_connected[g.camera_id] = False
            if not connected and error:
                faults.append(Fault(LOST, error, True, g.camera_id))
        return tuple(faults)


class ServiceSink:
    """The live outputs of each step: command and detections on the bus (the safety message
    first), alerts on the bus and in the log, the log line of each command change and stall,
    the status queryable and the Prometheus gauges once a second."""

    def __init__(self, bus: SafetyBus, metrics: Metrics, grabbers: list,
                 notice: str | None = None) -> None:
        self.bus = bus
        # said in every command's reasons (the synthetic test model on a live camera)
        self.notice = Reason(TEST_MODEL_REASON, notice) if notice else None
        self.metrics = metrics
        self.grabbers = grabbers
        # per camera: the times and inference ms of its last 30 frames, its last person count
        self.frame_times: dict[str, deque[float]] = {}
        self.inference: dict[str, deque[float]] = {}
        self.persons: dict[str, int] = {}
        self.last_status = -math.inf
        self.when = wall_clock()  # the policy's monotonic times as the operator's local time
        self.recorder = None  # the incident recorder, for its status and gauges
        self.last_mutes: tuple | None = None  # the muted zones last put in the status
        # each camera's objects since commissioning (``Pipeline.objects``): the status's
        # ``changed_since_commissioning`` whenever one appears, goes or is accepted
        self.objects: dict = {}
        self.last_objects: tuple | None = None

    def on_step(self, step: Step) -> None:
        result = step.result
        cmd = result.command
        if self.notice is not None:
            cmd = dataclasses.replace(cmd, reasons=(*cmd.reasons, self.notice))
        # the safety message first, dashboards after; a command that waited past the bus's
        # stall_timeout since its decision (the process froze) goes out as a STOP instead
        self.bus.publish_command(cmd, decided_at=step.decided_at)
        for outcome in result.mute_outcomes:  # the pipeline's judgement answers the request
            self.bus.answer_mute(outcome)
        for accepted in result.accept_outcomes:  # so is the judgement of an acceptance
            self.bus.answer_accept(accepted)
        self.mute_status(result)
        self.objects_status()
        if step.frame is not None:
            # the body's "frame" holds camera, seq, capture time and size (no override here)
            cam = step.frame.info.camera_id
            # where lost persons could be (the console draws why the cell is held)
            self.bus.publish_detections(result.persons, result.zone_report,
                                        **screen_body(result.areas, result.unseen,
                                                    result.pockets, cam))
            self.frame_times.setdefault(cam, deque(maxlen=30)).append(result.now)
            self.inference.setdefault(cam, deque(maxlen=30)).append(
                result.stage_ms.get("inference", 0.0))
            if result.persons is not None:
                self.persons[cam] = len(result.persons)
        if step.stalled_s is not None:
            event("monitor stalled: STOP latched", logging.ERROR, gap_s=round(step.stalled_s, 3))
        if result.changed:
            event(f"command {cmd.state}", logging.WARNING if cmd.state != "RUN" else logging.INFO,
                  **command_fields(result.command, self.when, self.notice))
        if step.reset_possible:
            event("reset possible: no STOP cause holds", logging.INFO)
        for alert in result.alerts:
            self.alert(alert)
        if result.now - self.last_status >= 1.0:
            self.last_status = result.now
            self.status(result)

    def mute_status(self, result: StepResult) -> None:
        """The muted zones in the status (with operator and end time) whenever they change."""
        mutes = tuple((m.zone, m.request_id) for m in result.mutes)
        if mutes == self.last_mutes:
            return
        self.last_mutes = mutes
        wall = time.time()
        self.bus.update_status(muted=[
            {"zone": m.zone, "operator": m.operator, "as": m.as_,
             "speed_scale": m.scale if m.as_ == "warning" else None, "max_s": m.max_s,
             "duration_s": m.end - m.start, "until_wall": wall + (m.end - result.now),
             "until": self.when(m.end), "request_id": m.request_id} for m in result.mutes])

    def objects_status(self) -> None:
        """The objects standing since commissioning in the status, whenever they change
        (``monitor status``: "cell changed since commissioning: ...")."""
        signature = changed_signature(self.objects)
        if signature == self.last_objects:
            return
        self.last_objects = signature
        self.bus.update_status(changed_since_commissioning=changed_cell(self.objects))

    def alert(self, alert: Alert) -> None:
        self.metrics.alerts.labels(alert.kind).inc()
        if self.bus.publish_alert(alert):
            level = {"info": logging.INFO, "critical": logging.ERROR}.get(alert.severity,
                                                                         logging.WARNING)
            event(f"alert {alert.kind}", level, severity=alert.severity, message=alert.message)

    def status(self, result: StepResult) -> None:
        statuses = [g.status() for g in self.grabbers]
        figures = [CameraFigures(
            s.camera_id, _fps(self.frame_times.get(s.camera_id, ())),
            statistics.median(self.inference[s.camera_id]) if self.inference.get(s.camera_id)
            else 0.0, s.dropped, s.connected, self.persons.get(s.camera_id)) for s in statuses]
        every = sorted(t for times in self.frame_times.values() for t in times)[-30:]
        inference = [ms for q in self.inference.values() for ms in q]
        cameras = [{"id": s.camera_id, "connected": s.connected, "dropped": s.dropped,
                    "reconnects": s.reconnects, "last_error": s.last_error,
                    "fps": round(f.fps, 2)} for s, f in zip(statuses, figures, strict=True)]
        self.bus.update_status(
            fps=round(_fps(every), 2),
            inference_ms=round(statistics.median(inference) if inference else 0.0, 2),
            camera=cameras[0], cameras=cameras,
            zone_sets=list(result.command.zone_sets) or None)
        self.metrics.update(result.command.state, figures, self.bus.foreign_commands())
        m = self.metrics
        if self.recorder is not None:
            with contextlib.suppress(Exception):  # an extra's numbers never stop this sink
                rec = self.recorder.status()
                m.recording.set(int(rec["recording"]))
                m.recorder_dropped.set(rec.get("dropped_frames", 0))
                self.bus.update_status(recorder=rec)

    def close(self) -> None:
        pass


def _fps(times) -> float:
    """Frames per second over the frame times ``times`` (oldest first)."""
    times = list(times)
    if len(times) >= 2 and times[-1] > times[0]:
        return (len(times) - 1) / (times[-1] - times[0])
    return 0.0
