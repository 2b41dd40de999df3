"""`monitor run`: the headless service beside the pose tracker.

Start order: signal handlers -> config (validated, nothing opened yet) -> zones (an enabled
protective zone is required unless ``[zones] allow_no_protective = true``) -> model -> Zenoh bus
-> pose subscriber -> frame grabbers -> the driver loop (``monitor.driver``). Shutdown runs in
reverse with bounded joins; the bus sends a last STOP (reason ``shutdown``) before it closes.
SIGINT and SIGTERM stop the loop (exit 0); a process still there 1.5 s later, or a second
signal, publishes STOP best effort and exits at once.

The loop never waits for a frame longer than ``service.tick_s``: without frames the policy still
runs its timers, so a lost camera gives STOP within ``policy.frame_timeout``. A gap in the loop
itself longer than ``frame_timeout`` (process frozen) is a latched ``monitor_stalled`` STOP.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import statistics
import sys
import threading
import time
from collections import deque
from pathlib import Path

from monitor.bus import BusConfig, SafetyBus
from monitor.capacity import CameraDemand, Limits
from monitor.capacity import check as capacity_check
from monitor.cases.receiver import CaseReceiver
from monitor.config import DEMO_SOURCE, MonitorConfig, demo_cell_path, load_config
from monitor.detector.test_model import TEST_MODEL_REASON, require_real_model
from monitor.driver import (
    Driver,
    Step,
    StepInputs,
    protective_warning,
    require_protective_zone,
)
from monitor.errors import ConfigError
from monitor.geometry import ReactionBudget, describe_separation
from monitor.health import LOST
from monitor.metrics import CameraFigures, Metrics
from monitor.pipeline import Pipeline, StepResult
from monitor.policy import STOP, Command, Reason
from monitor.reaction import (
    Allowances,
    MeasuredBudget,
    ReactionSink,
    ReactionWatch,
    at_start,
)
from monitor.resets import LatchNonces
from monitor.signals import StopSignals
from monitor.timetext import TimeText, wall_clock
from monitor.types import Alert, Fault
from monitor.zones.separation import (
    require_separation_ready,
    tool_points_in_tracker,
    with_reaction_time,
)

log = logging.getLogger("monitor")


class _JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        body = {"time": round(record.created, 3), "level": record.levelname.lower(),
                "event": record.getMessage()}
        body.update(getattr(record, "fields", {}))
        return json.dumps(body, default=str)


def setup_logging(as_json: bool) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_JsonFormatter() if as_json else
                         logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    log.handlers[:] = [handler]
    log.setLevel(logging.INFO)
    log.propagate = False


def command_fields(cmd: Command, when: TimeText, notice: Reason | None = None) -> dict:
    """The fields of a command change's log line: one ``describe`` (latch cause, what holds
    now, whether a reset is possible; times in ``when``'s clock), never a second list of
    reasons beside it that could say otherwise (the bus payload has them, as numbers)."""
    text = cmd.describe(when)
    if notice is not None:
        text += f" [{notice.message}]"
    return {"speed_scale": cmd.speed_scale, "latched": cmd.latched,
            "reset_possible": cmd.reset_possible, "describe": text}


def event(message: str, level: int = logging.INFO, /, **fields) -> None:
    """One line per event; fields go into the JSON object (or after the message).
    Positional-only, so a field may be called ``message`` (alerts have one)."""
    text = message if not fields else message + " " + " ".join(
        f"{k}={v}" for k, v in fields.items())
    log.log(level, text if not _json_logging() else message, extra={"fields": fields})


def _json_logging() -> bool:
    return any(isinstance(h.formatter, _JsonFormatter) for h in log.handlers)


def bus_config_for(config: MonitorConfig, cell) -> BusConfig:
    """The bus config with the active zone set's hash filled in."""
    return dataclasses.replace(config.bus, config_hash=cell.config_hash if cell else "")





def _require_fed_cameras(cell, config: MonitorConfig, zones_file: str | None) -> None:
    """A protective or warning image zone of a camera that no [[camera]] feeds would never
    see anyone: refused (a zone file edited for a new camera, the config not yet)."""
    if cell is None:
        return
    fed = {c.id for c in config.cameras}
    unfed = [z for z in cell.zones if z.enabled and z.shape == "polygon"
             and z.kind in ("protective", "warning") and z.camera not in fed]
    if unfed:
        z = unfed[0]
        raise ConfigError(f"zone '{z.id}' of {zones_file} is on camera '{z.camera}', which no "
                          f"[[camera]] of the config feeds: it would never see a person (add "
                          f"the camera: 'monitor zones camera add ... --config')")


def build_pipeline(config: MonitorConfig):
    """Model, zones, health checker and pipeline from a validated config (I/O: files only);
    also the warning to carry when the synthetic test model is allowed on a live camera."""
    from monitor.detector import Detector
    from monitor.health import CameraHealth, load_reference
    from monitor.models import synthetic
    from monitor.zones import load_cell, watch_regions

    zones_file = zones_file_of(config)
    cell = load_cell(zones_file) if zones_file else None
    zone_checks(config, cell, zones_file)
    health, expected = {}, {}
    for cam in config.cameras:
        reference = load_reference(cam.reference) if cam.reference else None
        watch = watch_regions(cell, cam.id) if cell is not None else []
        health[cam.id] = CameraHealth(config.health, cam.id, reference, watch)
        expected[cam.id] = (cell.cameras[cam.id].width, cell.cameras[cam.id].height) \
            if cell else None
    model = Path(config.model.path) if config.model.path else synthetic.ensure_model()
    detector = Detector(model, config.detector)  # one model, shared by the cameras in turn
    test_model = require_real_model(detector.test_model, config.cameras,
                                    config.model.allow_test_model)
    pipeline = Pipeline(detector, [c.id for c in config.cameras], config.policy, cell, health)
    pipeline.prepared = prepared_zones(config, cell)
    return pipeline, cell, expected, test_model


def zones_file_of(config: MonitorConfig) -> str | None:
    """The zone file the service runs with (the demo cell for the demo source), or None."""
    zones_file = config.zones.file
    if zones_file is None and all(c.source == DEMO_SOURCE for c in config.cameras):
        zones_file = str(demo_cell_path())
    return zones_file


def zone_checks(config: MonitorConfig, cell, zones_file: str | None) -> None:
    """What a zone set must pass to be decided with, at start and at a signed apply
    (monitor.zone_swap): a protective zone, every fed camera in it, no zone of an unfed
    camera, and a tool with a calibrated camera for separation monitoring. ConfigError."""
    require_protective_zone(cell, config.zones.allow_no_protective,
                            zones_file or "(no [zones] file)")
    for cam in config.cameras:
        if cell is not None and cam.id not in cell.cameras:
            raise ConfigError(f"camera {cam.id!r} is not in zone file {zones_file} "
                              f"(has {', '.join(cell.cameras)})")
    _require_fed_cameras(cell, config, zones_file)
    if config.policy.separation_monitoring:
        if cell is None:
            raise ConfigError("policy.separation_monitoring needs a zone file with a tool and a "
                              "calibrated camera ([zones] file)")
        require_separation_ready(cell)


def prepared_zones(config: MonitorConfig, cell):
    """The cell's prepared zones as the pipeline decides with them (None: no cell)."""
    if cell is None:
        return None
    if config.policy.separation_monitoring or cell.prepared.moving:
        # T_r is never smaller than the delays this configuration lets pass (ISO/TS 15066);
        # zones that grow with the tool speed use S_p too
        return with_reaction_time(cell.prepared, reaction_budget(config))
    return cell.prepared


def check_capacity(config: MonitorConfig, detector, expected: dict, mode: str,
                   stopped=lambda: False):
    """Time the detector on each camera's frame size (the zone file's, else 1920x1080) and
    refuse (or warn about) a host that cannot watch the cell within the limits."""
    demands = [CameraDemand(c.id, *(expected.get(c.id) or (1920, 1080)), c.max_fps)
               for c in config.cameras]
    limits = Limits(config.policy.frame_timeout, config.policy.max_frame_age,
                    config.bus.stall_timeout)
    return capacity_check(detector.detect, demands, limits, mode, stopped)


def reaction_budget(config: MonitorConfig) -> ReactionBudget:
    """The worst-case delays of this configuration (seconds): a frame may arrive as late as
    ``frame_timeout`` before the cell STOPs anyway, be ``max_frame_age`` old when decided on, a
    lost STOP leaves the consumer on the last RUN for ``ttl_ms``, and the pose may be
    ``pose_timeout`` old."""
    policy = config.policy
    return ReactionBudget(frame_interval_s=policy.frame_timeout,
                          max_frame_age_s=policy.max_frame_age,
                          processing_s=config.service.tick_s,
                          command_ttl_s=config.bus.ttl_ms / 1000.0,
                          consumer_reaction_s=config.reaction.consumer_reaction_ms / 1000.0,
                          pose_age_s=policy.pose_timeout)


def int8_at_start(config: MonitorConfig, detector, expected: dict, stopped):
    """The int8 model beside the configured one, timed against it here (monitor/int8hint.py);
    None without one. Never switches the model."""
    from monitor.detector import Detector
    from monitor.errors import MonitorError
    from monitor.int8hint import int8_hint

    size = max((expected.get(c.id) or (1920, 1080) for c in config.cameras),
               key=lambda s: s[0] * s[1])
    try:
        return int8_hint(detector.model_path, detector.detect,
                         lambda path: Detector(path, config.detector).detect, size, stopped)
    except MonitorError as exc:  # an unusable int8 file is no reason not to start
        event(f"int8 model beside the model not usable: {exc}", logging.WARNING)
        return None


def reaction_sink(config: MonitorConfig, pipeline: Pipeline, capacity, bus: SafetyBus,
                  metrics: Metrics, alert) -> ReactionSink:
    """The measured reaction budget (monitor/reaction.py) against the T_r that S_p was
    computed with (without separation monitoring: this configuration's T_r, and a warning
    only): judged at start from the capacity check's figures (log, alert, status), then live
    from the steps."""
    separation = (pipeline.prepared.separation if config.policy.separation_monitoring
                  and pipeline.prepared is not None else None)
    configured = (separation.reaction_time_s if separation is not None
                  else reaction_budget(config).total_s())
    speed = (pipeline.prepared.cell.spec.separation.programmed_speed_mps
             if separation is not None else None)
    allowances = Allowances(
        bus_hop_s=config.reaction.bus_hop_ms / 1000.0, command_ttl_s=config.bus.ttl_ms / 1000.0,
        consumer_reaction_s=config.reaction.consumer_reaction_ms / 1000.0,
        pose_age_s=config.policy.pose_timeout if separation is not None else 0.0)
    watch = ReactionWatch(configured, config.reaction.alert_repeat_s, separation, speed,
                          "critical" if separation is not None else "warning")
    verdicts: dict = {}
    if capacity is not None:
        start = at_start(capacity.frame_s, capacity.processed_fps, capacity.frame_age_s,
                         allowances)
        verdicts, alerts = watch.update(start, time.monotonic())
        for v in verdicts.values():
            event(f"reaction budget{' EXCEEDED' if v.exceeded else ''}: {v.message}",
                  logging.ERROR if v.exceeded else logging.INFO)
        for a in alerts:
            alert(a)
    return ReactionSink(MeasuredBudget(allowances), watch, alert, bus.update_status,
                        metrics.registry, config.reaction.check_period_s, verdicts)


def run_service(config_path: str | Path | None, log_json: bool = False,
                duration: float | None = None, stop: threading.Event | None = None,
                signals: StopSignals | None = None, capacity_check: str | None = None) -> int:
    """The service until ``duration`` has passed or a signal (or ``stop``) ends it.

    ``signals``: handlers the caller installed as early as it could (``monitor run`` does so
    before the model runtime is imported); without them they are installed here.
    ``capacity_check``: overrides ``[service] capacity_check`` ("refuse", "warn", "off").
    """
    own_signals = signals is None
    signals = signals or StopSignals(name="monitor run", stop=stop).install()
    try:
        return _run(config_path, log_json, duration, signals, capacity_check)
    finally:
        if own_signals:
            signals.restore()


def _run(config_path, log_json: bool, duration: float | None, signals: StopSignals,
         capacity_check: str | None = None) -> int:
    from monitor.frames import LatestFrameGrabber, SourceOptions, open_source

    stop = signals.stop
    setup_logging(log_json)
    config = load_config(config_path)
    if log_json is False and config.service.log_json:
        setup_logging(True)
    pipeline, cell, expected, test_model = build_pipeline(config)
    if stop.is_set():  # told to stop while the model loaded: nothing opened yet
        event("stopped before start")
        return 0
    event("started", config=str(config_path or "embedded demo"),
          cameras=",".join(f"{c.id}={c.source}" for c in config.cameras),
          zones=cell.label if cell else "none",
          config_hash=cell.config_hash if cell else "")
    warning = protective_warning(cell)
    if warning:
        event(warning, logging.WARNING)
    if test_model:
        event(test_model, logging.WARNING)
    for doubt in cell.warnings if cell else ():  # e.g. zone floor accepted as unobserved
        event(f"zone file {cell.label}: {doubt}", logging.WARNING)
    if config.bus.allow_unsigned_resets:
        event("resets are accepted without an operator key (embedded demo on 127.0.0.1, or "
              "allow_unsigned_resets = true): not for a production cell", logging.WARNING)
    if config.policy.separation_monitoring and pipeline.prepared is not None:
        event(describe_separation(pipeline.prepared.separation,
                                  cell.spec.separation.programmed_speed_mps,
                                  reaction_budget(config)))
    metrics = Metrics(config.service.metrics_port, config.service.metrics_host)
    closers: list = []  # the recorder's, run after the bus's final STOP (bounded)
    try:
        with SafetyBus(bus_config_for(config, cell), alert_limits=config.alerts) as bus:
            forget = signals.on_force(lambda: bus.publish_command(shutdown_forced()))
            pipeline.latch_nonces = LatchNonces(bus.boot)  # resets name this run's latches
            pipeline.when = wall_clock()  # mute reasons say "until 14:03:12"
            event("bus open", key_prefix=bus.config.key_prefix, zid=bus.boot,
                  listen=",".join(bus.config.listen), connect=",".join(bus.config.connect))
            if warning:
                bus.update_status(protective_zone=False, warning=warning)
            if test_model:
                bus.update_status(test_model=test_model)
            # zone set selections (monitor/cases/): only with sets in the zone file
            cases = (CaseReceiver.for_bus(bus.session, bus.config, pipeline.case_plan)
                     if pipeline.case_plan is not None else None)
            if cases is not None:
                cases.__enter__()
                closers.append(cases.close)
                event("zone sets", default=pipeline.case_plan.default, key=cases.key_expr,
                      selectors=bus.config.selectors_file or "none (every selection refused)")
            try:
                # the embedded demo's capacity only warns: a demonstration, not a cell
                _serve(config, pipeline, bus, expected, metrics, stop, duration,
                       LatestFrameGrabber, SourceOptions, open_source, test_model,
                       capacity_check or ("warn" if config_path is None
                                          else config.service.capacity_check),
                       closers, cases)
            finally:
                forget()
            event("shutting down: final STOP published")
    finally:
        for close in closers:
            with contextlib.suppress(Exception):
                close()
        metrics.close()
    event("stopped")
    return 0


def shutdown_forced() -> Command:
    return Command(STOP, 0.0, (Reason("shutdown", "monitor shutting down (forced)"),),
                   since=time.monotonic())


def _serve(config: MonitorConfig, pipeline: Pipeline, bus: SafetyBus, expected: dict, metrics,
           stop: threading.Event, duration: float | None, grabber_cls, options_cls,
           open_source, test_model: str | None = None, capacity_mode: str = "refuse",
           closers: list | None = None, cases=None) -> None:
    # zones that follow the tool need the pose too (without it they stay at their maximum)
    following = pipeline.prepared is not None and bool(pipeline.prepared.moving)
    pose = (bus.pose_subscriber(tracker_clock=config.tracker_clock)
            if config.policy.separation_monitoring or following else None)
    if pose is not None:
        pose.__enter__()
    grabbers: list = []
    closers = closers if closers is not None else []
    try:
        for cam in config.cameras:
            if stop.is_set():
                return
            source = open_source(cam.source, cam.id, realtime=cam.realtime,
                                 options=options_cls(loop=cam.loop), stop=stop)
            grabbers.append(grabber_cls(source, stop=stop,
                                        expected_size=expected[cam.id]).start())
        # after every file and camera opened (their errors come first), with the grabbers
        # already decoding: the load the loop will see
        capacity = check_capacity(config, pipeline.detector, expected, capacity_mode,
                                  stop.is_set)
        if capacity is not None:
            event(capacity.describe())
            for line in capacity.warnings:
                event(f"capacity: {line}", logging.WARNING)
            bus.update_status(capacity=capacity.to_dict())
            int8 = int8_at_start(config, pipeline.detector, expected, stop.is_set)
            if int8 is not None:
                event(int8.message())
                bus.update_status(int8=int8.to_dict())
        sink = ServiceSink(bus, metrics, grabbers, notice=test_model)
        recorder = None
        if config.recorder.enabled:  # an optional extra: never a reason not to command
            from monitor.incidents.live import start_recorder

            recorder = start_recorder(config, pipeline.cell, bus, metrics, sink.alert, event)
        if recorder is not None:
            sink.recorder = recorder[0]
            closers.append(recorder[1])
        feed = LiveFeed(grabbers, bus, pose, config.service.tick_s, stop, duration,
                        sink.alert, pipeline.prepared,
                        max_fps={c.id: c.max_fps for c in config.cameras})
        # signed zone applies: checked on the bus, swapped in by the loop between two steps
        from monitor.zone_swap import LiveZones, ZoneApplies

        applies = ZoneApplies(bus)
        closers.insert(0, applies.close)
        rec = recorder[0] if recorder is not None else None

        def applied(cell) -> None:
            feed.use_zones(pipeline.prepared)
            if rec is not None:
                rec.zones_changed(cell)

        feed.zones = LiveZones(config, zones_file_of(config), pipeline, bus, applies,
                               sink.alert, event, on_applied=applied)
        bus.update_status(zones_file=zones_file_of(config) or "")
        feed.cases = cases
        # after the service's sink: the command of a step is published when it times it
        reaction = reaction_sink(config, pipeline, capacity, bus, metrics, sink.alert)
        # the safety sink first; the recorder (an optional extra) last
        sinks = [sink, reaction] if recorder is None else [sink, reaction, recorder[0]]
        driver = Driver(pipeline, sinks, stall_after_s=config.policy.frame_timeout,
                        self_test_period_s=getattr(config.detector, "self_test_period_s", None))
        # cameras whose frames are ready together share one inference (dynamic-batch models)
        batch = config.detector.batch_cameras and len(grabbers) > 1 \
            and pipeline.detector.batchable
        if len(grabbers) > 1:
            event("batching the cameras' frames" if batch else "cameras' frames run in turn",
                  cameras=len(grabbers))
        driver.run(feed, stop, batch=batch)
    finally:
        stop.set()
        for grabber in reversed(grabbers):
            if not grabber.stop(timeout=0.5):  # a read blocked in a driver: daemon thread
                event("frame grabber did not stop in time", logging.WARNING,
                      camera=grabber.camera_id)
        if pose is not None:
            pose.__exit__(None, None, None)


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
        self.zones = None  # monitor.zone_swap.LiveZones: signed zone applies, between steps
        self.bus = bus
        self.pose = pose
        self.stop = stop
        self.alert = alert
        self.wait = tick_s / len(grabbers)
        self.end = time.monotonic() + duration if duration is not None else None
        self.turn = 0
        self.cases = None  # the zone set selections' receiver (None: no sets)
        # None: never connected yet (start-up is no loss); True / False after that
        self.was_connected: dict[str, bool | None] = {g.camera_id: None for g in grabbers}

    def use_zones(self, prepared) -> None:
        """The tool points whose speed bounds the whole tool's (none without a tool)."""
        self.tool_points = tool_points_in_tracker(prepared) if prepared is not None else None
        self.unknown_speed = (prepared.separation.robot_speed_default_mps
                              if prepared is not None else 0.0)

    def next(self):
        if self.end is not None and time.monotonic() >= self.end:
            return None
        grabber = self.grabbers[self.turn % len(self.grabbers)]
        self.turn += 1
        if not self._due(grabber.camera_id):  # [camera] max_fps: this camera waits its turn
            self.stop.wait(self.wait)
            return None, time.monotonic()
        frame = grabber.get(timeout=self.wait)
        if frame is not None:
            self.last_taken[grabber.camera_id] = time.monotonic()
        elif not grabber.alive:  # the source ended: get() no longer waits
            self.stop.wait(self.wait)
        return frame, time.monotonic()

    def next_batch(self):
        """Every camera's newest frame that is ready now (waiting, bounded, only for the camera
        whose turn it is): ``(frames, now)``, frames possibly empty (a timer tick)."""
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
            frame = grabber.get(timeout=0.0 if waited else self.wait)
            waited = True
            if frame is not None:
                frames.append(frame)
                self.last_taken[grabber.camera_id] = time.monotonic()
        if not frames and (not waited or not any(g.alive for g in self.grabbers)):
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
                from monitor.alerts import pose_alert

                self.alert(pose_alert(rejection, "pose", now))
        return StepInputs(reset=resets[-1] if resets else None,
                          extra_faults=tuple(faults), tool_pose=tool_pose,
                          tool_speed_mps=tool_speed, pose_time=pose_time,
                          mutes=self.bus.poll_mutes(), case_events=case_events)

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
        self.mute_status(result)
        if step.frame is not None:
            # the body's "frame" holds camera, seq, capture time and size (no override here)
            self.bus.publish_detections(result.persons, result.zone_report)
            cam = step.frame.info.camera_id
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
