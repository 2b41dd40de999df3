"""`monitor run`: the headless service beside the pose tracker.

Start order: config (validated, nothing opened yet) -> model -> zones -> Zenoh bus -> pose
subscriber -> frame grabber -> loop. Shutdown runs in reverse with bounded joins; the bus sends
a last STOP (reason ``shutdown``) before it closes. SIGINT and SIGTERM stop the loop; exit 0.

The loop never waits for a frame longer than ``service.tick_s``: without frames the policy still
runs its timers, so a lost camera gives STOP within ``policy.frame_timeout``.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import logging
import math
import signal
import statistics
import sys
import threading
import time
from collections import deque
from pathlib import Path

from monitor.bus import BusConfig, SafetyBus
from monitor.config import DEMO_SOURCE, MonitorConfig, demo_cell_path, load_config
from monitor.errors import ConfigError
from monitor.health import LOST
from monitor.pipeline import Pipeline, StepResult
from monitor.types import Alert, Fault

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


class Metrics:
    """Prometheus gauges and counters, served on 127.0.0.1:<port> when the port is set."""

    def __init__(self, port: int, host: str) -> None:
        from prometheus_client import CollectorRegistry, Counter, Gauge, start_http_server

        self.registry = CollectorRegistry()
        r = self.registry
        self.fps = Gauge("monitor_fps", "processed frames per second", registry=r)
        self.inference_ms = Gauge("monitor_inference_ms", "inference time of the last frame",
                                  registry=r)
        self.state = Gauge("monitor_state", "0 RUN, 1 SLOW, 2 STOP", registry=r)
        self.dropped = Gauge("monitor_dropped_frames", "frames dropped by the grabber",
                             registry=r)
        self.alerts = Counter("monitor_alerts", "alerts raised", ["kind"], registry=r)
        self.persons = Gauge("monitor_persons", "persons in the last frame", registry=r)
        self.server = None
        if port:
            try:
                self.server, self._thread = start_http_server(port, addr=host, registry=r)
            except OSError as exc:
                raise ConfigError(f"service.metrics_port: cannot serve metrics on "
                                  f"{host}:{port}: {exc.strerror or exc}") from None

    def close(self) -> None:
        if self.server is not None:
            self.server.shutdown()


STATE_LEVEL = {"RUN": 0, "SLOW": 1, "STOP": 2}


def build_pipeline(config: MonitorConfig):
    """Model, zones, health checker and pipeline from a validated config (I/O: files only)."""
    from monitor.detector import Detector
    from monitor.health import CameraHealth, load_reference
    from monitor.models import synthetic
    from monitor.zones import load_cell, watch_regions

    zones_file = config.zones.file
    if zones_file is None and all(c.source == DEMO_SOURCE for c in config.cameras):
        zones_file = str(demo_cell_path())
    cell = load_cell(zones_file) if zones_file else None
    health, expected = {}, {}
    for cam in config.cameras:
        if cell is not None and cam.id not in cell.cameras:
            raise ConfigError(f"camera {cam.id!r} is not in zone file {zones_file} "
                              f"(has {', '.join(cell.cameras)})")
        reference = load_reference(cam.reference) if cam.reference else None
        watch = watch_regions(cell, cam.id) if cell is not None else []
        health[cam.id] = CameraHealth(config.health, cam.id, reference, watch)
        expected[cam.id] = (cell.cameras[cam.id].width, cell.cameras[cam.id].height) \
            if cell else None
    model = Path(config.model.path) if config.model.path else synthetic.ensure_model()
    detector = Detector(model, config.detector)  # one model, shared by the cameras in turn
    pipeline = Pipeline(detector, [c.id for c in config.cameras], config.policy, cell, health)
    return pipeline, cell, expected


def run_service(config_path: str | Path | None, log_json: bool = False,
                duration: float | None = None, stop: threading.Event | None = None) -> int:
    from monitor.frames import LatestFrameGrabber, SourceOptions, open_source

    setup_logging(log_json)
    config = load_config(config_path)
    if log_json is False and config.service.log_json:
        setup_logging(True)
    stop = stop or threading.Event()
    pipeline, cell, expected = build_pipeline(config)
    event("started", config=str(config_path or "embedded demo"),
          cameras=",".join(f"{c.id}={c.source}" for c in config.cameras),
          zones=cell.label if cell else "none",
          config_hash=cell.config_hash if cell else "")
    if cell is None:
        event("no zone file: persons are detected but cannot cause SLOW or STOP",
              logging.WARNING)
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    if threading.current_thread() is threading.main_thread():
        for s in previous:
            signal.signal(s, lambda *_: stop.set())
    metrics = Metrics(config.service.metrics_port, config.service.metrics_host)
    try:
        with SafetyBus(bus_config_for(config, cell), alert_limits=config.alerts) as bus:
            event("bus open", key_prefix=bus.config.key_prefix, zid=bus.boot,
                  listen=",".join(bus.config.listen), connect=",".join(bus.config.connect))
            pose = bus.pose_subscriber() if config.policy.separation_monitoring else None
            if pose is not None:
                pose.__enter__()
            try:
                grabbers = []
                try:
                    for cam in config.cameras:
                        source = open_source(cam.source, cam.id, realtime=cam.realtime,
                                             options=SourceOptions(loop=cam.loop), stop=stop)
                        grabbers.append(LatestFrameGrabber(
                            source, stop=stop, expected_size=expected[cam.id]).start())
                    _loop(config, pipeline, bus, grabbers, pose, metrics, stop, duration)
                finally:
                    stop.set()
                    for grabber in reversed(grabbers):
                        if not grabber.stop(timeout=2.0):
                            event("frame grabber did not stop in time", logging.WARNING,
                                  camera=grabber.camera_id)
            finally:
                if pose is not None:
                    pose.__exit__(None, None, None)
            event("shutting down: final STOP published")
    finally:
        metrics.close()
        if threading.current_thread() is threading.main_thread():
            for s, handler in previous.items():
                signal.signal(s, handler)
    event("stopped")
    return 0


def _loop(config: MonitorConfig, pipeline: Pipeline, bus: SafetyBus, grabbers: list, pose,
          metrics, stop: threading.Event, duration: float | None) -> None:
    """Cameras take turns (round robin); each wait is bounded, so timers run without frames."""
    started = time.monotonic()
    frame_times: deque[float] = deque(maxlen=30)
    inference: deque[float] = deque(maxlen=30)
    last_status = 0.0
    was_connected = {g.camera_id: True for g in grabbers}
    wait = config.service.tick_s / len(grabbers)
    for turn in itertools.count():
        if stop.is_set():
            break
        now = time.monotonic()
        if duration is not None and now - started >= duration:
            break
        grabber = grabbers[turn % len(grabbers)]
        frame = grabber.get(timeout=wait)
        if frame is None and not grabber.alive:  # the source ended: get() no longer waits
            stop.wait(wait)
        now = time.monotonic()
        resets = bus.poll_resets()
        reset = resets[-1] if resets else None
        pose_time = tool_pose = tool_speed = None
        if pose is not None:
            reading = pose.latest()
            if reading is not None:
                pose_time, tool_pose = reading.received, reading.tool_pose()
                tool_speed = math.hypot(*reading.sample.velocity_m_s)  # for S_p (ISO/TS 15066)
            for rejection in pose.drain_rejections():
                from monitor.alerts import pose_alert

                _alert(bus, metrics, pose_alert(rejection, "pose", now))
        # A loss a grabber has seen (read/open error, wrong size, end of stream) is a STOP
        # cause at once, with the camera's own error; frame_timeout is only the backstop.
        extra = []
        for g in grabbers:
            connected = g.connected
            if connected != was_connected[g.camera_id]:
                event("camera lost" if not connected else "camera reconnected",
                      logging.WARNING if not connected else logging.INFO,
                      camera=g.camera_id, error=g.status().last_error)
                was_connected[g.camera_id] = connected
            if not connected and g.last_error:
                extra.append(Fault(LOST, g.last_error, True, g.camera_id))
        extra = tuple(extra)
        if frame is not None:
            result = pipeline.process(frame.image, frame.info, now, tool_pose=tool_pose,
                                      tool_speed_mps=tool_speed, pose_time=pose_time,
                                      reset=reset, extra_faults=extra)
            frame_times.append(now)
            inference.append(result.stage_ms.get("inference", 0.0))
        else:
            result = pipeline.tick(now, pose_time=pose_time, reset=reset, extra_faults=extra)
        bus.publish_command(result.command)  # the safety message first, dashboards after
        if frame is not None:
            # the body's "frame" holds camera, seq, capture time and size (no override here)
            bus.publish_detections(result.persons, result.zone_report)
        if result.changed:
            cmd = result.command
            event(f"command {cmd.state}", logging.WARNING if cmd.state != "RUN" else logging.INFO,
                  speed_scale=cmd.speed_scale, latched=cmd.latched,
                  reasons="; ".join(r.message for r in cmd.reasons) or "-")
        alerts = list(result.alerts)
        if result.command.reset is not None:
            from monitor.alerts import reset_alert

            alerts.append(reset_alert(result.command.reset, pipeline.camera_id, now))
        for alert in alerts:
            _alert(bus, metrics, alert)
        if now - last_status >= 1.0:
            last_status = now
            _status(bus, metrics, grabbers, result, frame_times, inference)


def _alert(bus: SafetyBus, metrics: Metrics, alert: Alert) -> None:
    metrics.alerts.labels(alert.kind).inc()
    if bus.publish_alert(alert):
        level = {"info": logging.INFO, "critical": logging.ERROR}.get(alert.severity,
                                                                     logging.WARNING)
        event(f"alert {alert.kind}", level, severity=alert.severity, message=alert.message)


def _status(bus: SafetyBus, metrics: Metrics, grabbers: list, result: StepResult, frame_times,
            inference) -> None:
    fps = 0.0
    if len(frame_times) >= 2 and frame_times[-1] > frame_times[0]:
        fps = (len(frame_times) - 1) / (frame_times[-1] - frame_times[0])
    inf_ms = statistics.median(inference) if inference else 0.0
    statuses = [g.status() for g in grabbers]
    cameras = [{"id": s.camera_id, "connected": s.connected, "dropped": s.dropped,
                "reconnects": s.reconnects, "last_error": s.last_error} for s in statuses]
    bus.update_status(fps=round(fps, 2), inference_ms=round(inf_ms, 2), camera=cameras[0],
                      cameras=cameras)
    metrics.fps.set(fps)
    metrics.inference_ms.set(inf_ms)
    metrics.state.set(STATE_LEVEL[result.command.state])
    metrics.dropped.set(sum(s.dropped for s in statuses))
    if result.persons is not None:
        metrics.persons.set(len(result.persons))
