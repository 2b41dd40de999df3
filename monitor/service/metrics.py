"""Prometheus metrics of `monitor run`, served on 127.0.0.1:<service.metrics_port>.

Per camera (label ``camera``): ``monitor_fps``, ``monitor_inference_ms``,
``monitor_dropped_frames``, ``monitor_persons``, ``monitor_camera_connected``. The command state
is readable as one gauge per state, ``monitor_state{state="STOP"} 1`` (the others 0), and as a
level for thresholds, ``monitor_state_level`` (0 RUN, 1 SLOW, 2 STOP). ``monitor_alerts{kind}``
counts alerts, ``monitor_commands_foreign{kind}`` the ignored commands of other senders,
``monitor_incidents{cause}`` and ``monitor_recorder_*`` the incident recorder's work;
``monitor_detector_backend{backend,precision}`` 1 for the backend that runs the model and
``monitor_detector_backend_agreement`` its agreement with onnxruntime.
Dashboards only: the safety message is the command on the bus (docs/health.md).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from monitor.errors import ConfigError

STATES = ("RUN", "SLOW", "STOP")
STATE_LEVEL = {state: level for level, state in enumerate(STATES)}


@dataclass(frozen=True)
class CameraFigures:
    """One camera's figures for the gauges (dropped frames and connection from its grabber)."""

    camera_id: str
    fps: float
    inference_ms: float
    dropped: int
    connected: bool
    persons: int | None  # persons in its last processed frame; None before the first


class Metrics:
    """Prometheus gauges and counters, served on ``host:port`` when the port is set."""

    def __init__(self, port: int, host: str) -> None:
        from prometheus_client import CollectorRegistry, Counter, Gauge, start_http_server

        self.registry = CollectorRegistry()
        r = self.registry
        cam = ["camera"]
        self.fps = Gauge("monitor_fps", "processed frames per second", cam, registry=r)
        self.inference_ms = Gauge("monitor_inference_ms", "median inference time (ms) of the "
                                  "last frames", cam, registry=r)
        self.dropped = Gauge("monitor_dropped_frames", "frames dropped by the grabber", cam,
                             registry=r)
        self.persons = Gauge("monitor_persons", "persons in the camera's last frame", cam,
                             registry=r)
        self.connected = Gauge("monitor_camera_connected", "1 while the camera delivers frames",
                               cam, registry=r)
        self.state = Gauge("monitor_state", "1 for the command state now (RUN, SLOW or STOP), "
                           "0 for the others", ["state"], registry=r)
        self.state_level = Gauge("monitor_state_level", "command state: 0 RUN, 1 SLOW, 2 STOP",
                                 registry=r)
        self.alerts = Counter("monitor_alerts", "alerts raised", ["kind"], registry=r)
        self.foreign_commands = Gauge(
            "monitor_commands_foreign", "commands on the command key not from this monitor "
            "(unsigned, wrongly signed, ...), ignored", ["kind"], registry=r)
        # the incident recorder (an optional extra: docs/incidents.md)
        self.incidents = Counter("monitor_incidents", "incidents recorded, per cause",
                                 ["cause"], registry=r)
        self.recording = Gauge("monitor_recorder_recording", "1 while incidents are recorded "
                               "(0: stopped or off)", registry=r)
        self.recorder_dropped = Gauge("monitor_recorder_dropped_frames", "frames the recorder "
                                      "dropped to keep the safety loop at speed", registry=r)
        # which backend runs the model (monitor/detector/choice.py) and how its persons agree
        # with onnxruntime's on the agreement figures (1: it is onnxruntime)
        self.backend = Gauge("monitor_detector_backend", "1 for the backend and precision that "
                             "run the detector", ["backend", "precision"], registry=r)
        self.backend_agreement = Gauge("monitor_detector_backend_agreement", "persons found by "
                                       "the running backend and onnxruntime / by either",
                                       registry=r)
        self.set_state("STOP")  # what the monitor says until its first decision
        self.server = None
        if port:
            try:
                self.server, self._thread = start_http_server(port, addr=host, registry=r)
            except OSError as exc:
                raise ConfigError(f"service.metrics_port: cannot serve metrics on "
                                  f"{host}:{port}: {exc.strerror or exc}") from None

    def set_backend(self, backend: str, precision: str, agreement: float) -> None:
        self.backend.labels(backend, precision).set(1.0)
        self.backend_agreement.set(agreement)

    def set_state(self, state: str) -> None:
        for s in STATES:
            self.state.labels(s).set(1.0 if s == state else 0.0)
        self.state_level.set(STATE_LEVEL[state])

    def update(self, state: str, cameras: Iterable[CameraFigures],
               foreign: Mapping[str, int]) -> None:
        self.set_state(state)
        for c in cameras:
            self.fps.labels(c.camera_id).set(c.fps)
            self.inference_ms.labels(c.camera_id).set(c.inference_ms)
            self.dropped.labels(c.camera_id).set(c.dropped)
            self.connected.labels(c.camera_id).set(1.0 if c.connected else 0.0)
            if c.persons is not None:
                self.persons.labels(c.camera_id).set(c.persons)
        for kind, n in foreign.items():
            self.foreign_commands.labels(kind).set(n)

    def close(self) -> None:
        if self.server is not None:
            self.server.shutdown()
