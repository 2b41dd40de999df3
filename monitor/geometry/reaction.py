"""The reaction-time budget, measured: is the T_r that S_p was computed with long enough here?

``monitor run`` computes T_r from the configuration (``service_setup.reaction_budget``: the
delays the policy lets pass before it STOPs anyway). This module measures the same chain on the
host, per camera, from a person stepping in to the robot starting to brake:

* ``frame_interval_s``: the person may step in just after a frame was captured; the next one
  this camera processes comes this much later (p99 of the gaps between its processed frames);
* ``capture_to_command_s``: capture -> command published (p99: grabber wait, detection, zones,
  policy, signing and the put);
* ``bus_hop_s``: the command's way over Zenoh to the consumer (an allowance, ``[reaction]
  bus_hop_ms``: loopback p99 is 0.2-0.35 ms, a switched LAN about 1 ms);
* ``command_ttl_s``: a lost STOP leaves the consumer on the last RUN this long (bus.ttl_ms);
* ``consumer_reaction_s``: the robot controller's own reaction (``[reaction]``);
* ``pose_age_s``: how old the tool pose may be (policy.pose_timeout, with separation on).

At start the figures come from the capacity check's timing of the detector (``at_start``);
live, from the steps (``MeasuredBudget``), every few seconds. ``ReactionWatch`` compares each
camera's total with the configured T_r and alerts (critical, ``reaction_budget``) when it is
exceeded: S_p was then computed with too short a T_r, and the separation is too small. Pure,
except ``ReactionSink`` (the service's outputs) and ``reaction_gauges`` (Prometheus).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Annotated

from pydantic import Field

from monitor.geometry import SeparationParams, protective_separation_m
from monitor.schema import Float, section
from monitor.types import Alert

ALERT_KIND = "reaction_budget"
# p99 over this many recent frames of a camera (10 fps: the last 30 s)
WINDOW = 300
# fewer samples than this and the live p99 is not trusted yet (the start estimate stands)
MIN_SAMPLES = 20


@section("reaction")
class ReactionConfig:
    # the command's hop over the bus to the consumer, an allowance (ms): loopback p99 is
    # 0.2-0.35 ms, a switched LAN about 1 ms; raise it for routers or Wi-Fi between them
    bus_hop_ms: Annotated[Float, Field(ge=0, le=1000)] = 1.0
    # the robot controller's reaction to a STOP command (ms), part of T_r both as configured
    # and as measured
    consumer_reaction_ms: Annotated[Float, Field(ge=0, le=5000)] = 50.0
    # the live measured budget is recomputed this often (s)
    check_period_s: Annotated[Float, Field(ge=0.5, le=600)] = 5.0
    # an exceeded budget is alerted again at most this often per camera (s)
    alert_repeat_s: Annotated[Float, Field(ge=1, le=86400)] = 60.0


@dataclass(frozen=True)
class Allowances:
    """The parts of the budget that are not timed on this host (seconds)."""

    bus_hop_s: float
    command_ttl_s: float
    consumer_reaction_s: float
    pose_age_s: float = 0.0


@dataclass(frozen=True)
class MeasuredReaction:
    """One camera's measured reaction budget (seconds); ``source``: "start" or "live"."""

    camera_id: str
    frame_interval_s: float
    capture_to_command_s: float
    allowances: Allowances
    source: str = "live"

    @property
    def total_s(self) -> float:
        a = self.allowances
        return (self.frame_interval_s + self.capture_to_command_s + a.bus_hop_s
                + a.command_ttl_s + a.consumer_reaction_s + a.pose_age_s)

    def parts(self) -> str:
        a = self.allowances
        return (f"frame interval {self.frame_interval_s:.3f} + capture->command "
                f"{self.capture_to_command_s:.3f} + bus hop {a.bus_hop_s:.4f} + command ttl "
                f"{a.command_ttl_s:.3f} + consumer {a.consumer_reaction_s:.3f} + pose age "
                f"{a.pose_age_s:.3f} = {self.total_s:.3f} s")

    def to_dict(self) -> dict:
        a = self.allowances
        return {"measured_s": round(self.total_s, 4), "source": self.source,
                "frame_interval_s": round(self.frame_interval_s, 4),
                "capture_to_command_s": round(self.capture_to_command_s, 4),
                "bus_hop_s": a.bus_hop_s, "command_ttl_s": a.command_ttl_s,
                "consumer_reaction_s": a.consumer_reaction_s, "pose_age_s": a.pose_age_s}


def at_start(frame_s: float, processed_fps: Mapping[str, float],
             frame_age_s: Mapping[str, float], allowances: Allowances
             ) -> dict[str, MeasuredReaction]:
    """The budget estimated from the start-up capacity check
    (``monitor.service.capacity.Capacity``): a camera's processed frame interval is 1 / its
    processed fps, and its capture->command the worst age of its newest frame at a decision
    (interval + a frame's latency: a frame captured just after the grabber was read waits a whole
    interval) plus the publishing, within
    ``frame_s``'s allowance. Pure."""
    del frame_s  # part of frame_age_s already
    return {cam: MeasuredReaction(cam, 1.0 / fps if fps > 0 else math.inf,
                                  frame_age_s[cam], allowances, "start")
            for cam, fps in processed_fps.items()}


def p99(values) -> float:
    """The 99th percentile (nearest rank, the larger side: never optimistic)."""
    ordered = sorted(values)
    if not ordered:
        return math.nan
    return ordered[min(len(ordered) - 1, math.ceil(0.99 * len(ordered)) - 1)]


class MeasuredBudget:
    """Rolling p99 of each camera's processed-frame interval and capture->command (seconds),
    from the frames' capture times and the times their commands were published."""

    def __init__(self, allowances: Allowances, window: int = WINDOW,
                 min_samples: int = MIN_SAMPLES) -> None:
        self.allowances = allowances
        self.min_samples = min_samples
        self._latency: dict[str, deque[float]] = {}
        self._interval: dict[str, deque[float]] = {}
        self._last_capture: dict[str, float] = {}
        self._window = window

    def add(self, camera_id: str, capture_time: float, commanded_at: float) -> None:
        latency = self._latency.setdefault(camera_id, deque(maxlen=self._window))
        latency.append(max(0.0, commanded_at - capture_time))
        last = self._last_capture.get(camera_id)
        if last is not None and capture_time > last:
            self._interval.setdefault(camera_id, deque(maxlen=self._window)).append(
                capture_time - last)
        self._last_capture[camera_id] = capture_time

    def budgets(self) -> dict[str, MeasuredReaction]:
        """Each camera with enough samples: its p99 figures plus the allowances."""
        out = {}
        for cam, latency in self._latency.items():
            gaps = self._interval.get(cam, ())
            if len(latency) < self.min_samples or len(gaps) < self.min_samples - 1:
                continue
            out[cam] = MeasuredReaction(cam, p99(gaps), p99(latency), self.allowances)
        return out


def needed_separation_m(params: SeparationParams, programmed_speed_mps: float,
                        reaction_time_s: float) -> float:
    """S_p at the programmed speed with T_r = ``reaction_time_s``."""
    return protective_separation_m(
        programmed_speed_mps, dataclasses.replace(params, reaction_time_s=reaction_time_s))


@dataclass(frozen=True)
class Verdict:
    """One camera's measured budget against the configured T_r."""

    measured: MeasuredReaction
    configured_s: float
    exceeded: bool
    message: str


class ReactionWatch:
    """Compares measured budgets with the configured T_r; says when to alert.

    An exceeded budget is alerted when it is first seen (at start, or crossing up live), again
    at most every ``repeat_s`` while it stays exceeded, and once (info) when it is back within.
    ``params`` and ``programmed_speed_mps`` (separation monitoring) let the message say what
    S_p the measured budget would need."""

    def __init__(self, configured_s: float, repeat_s: float = 60.0,
                 params: SeparationParams | None = None,
                 programmed_speed_mps: float | None = None, severity: str = "critical") -> None:
        self.configured_s = configured_s
        self.severity = severity
        self.repeat_s = repeat_s
        self.params = params
        self.speed = programmed_speed_mps
        self.exceeded: dict[str, bool] = {}
        self.last_alert: dict[str, float] = {}

    def verdict(self, m: MeasuredReaction) -> Verdict:
        exceeded = not m.total_s <= self.configured_s  # NaN / inf: exceeded
        if exceeded:
            need = ""
            if self.params is not None and self.speed is not None:
                now_sp = needed_separation_m(self.params, self.speed, self.configured_s)
                need_sp = needed_separation_m(self.params, self.speed, m.total_s)
                need = (f"; S_p at the programmed {self.speed:g} m/s would need {need_sp:.2f} m "
                        f"instead of {now_sp:.2f} m: the separation is too small")
            message = (f"camera {m.camera_id}: measured reaction budget {m.total_s:.3f} s "
                       f"({m.source}) exceeds the T_r {self.configured_s:.3f} s that S_p was "
                       f"computed with{need} ({m.parts()}); lower the delays (faster frames, "
                       f"shorter ttl) or raise the zone file's reaction_time_s")
        else:
            message = (f"camera {m.camera_id}: measured reaction budget {m.total_s:.3f} s "
                       f"({m.source}) within T_r {self.configured_s:.3f} s ({m.parts()})")
        return Verdict(m, self.configured_s, exceeded, message)

    def update(self, budgets: Mapping[str, MeasuredReaction], now: float
               ) -> tuple[dict[str, Verdict], list[Alert]]:
        """The verdict of each camera and the alerts to raise now."""
        verdicts, alerts = {}, []
        for cam, m in budgets.items():
            v = self.verdict(m)
            verdicts[cam] = v
            was = self.exceeded.get(cam, False)
            self.exceeded[cam] = v.exceeded
            details = {"camera": cam, "configured_s": round(self.configured_s, 4),
                       **m.to_dict()}
            if v.exceeded:
                last = self.last_alert.get(cam)
                if not was or last is None or now - last >= self.repeat_s:
                    self.last_alert[cam] = now
                    alerts.append(Alert(ALERT_KIND, self.severity, v.message, cam, now,
                                        details=details))
            elif was:
                alerts.append(Alert(ALERT_KIND, "info", v.message, cam, now, details=details))
        return verdicts, alerts


def status_of(verdicts: Mapping[str, Verdict], configured_s: float) -> dict:
    """The ``reaction_budget`` field of the status."""
    return {"configured_s": round(configured_s, 4),
            "exceeded": any(v.exceeded for v in verdicts.values()),
            "cameras": {cam: {**v.measured.to_dict(), "exceeded": v.exceeded}
                        for cam, v in verdicts.items()}}


def reaction_gauges(registry):
    """Prometheus gauges of the budget, on the service's registry (kept apart from
    ``monitor.service.metrics.Metrics``): measured per camera, configured, exceeded per camera."""
    from prometheus_client import Gauge

    return (Gauge("monitor_reaction_budget_seconds", "measured reaction budget (p99 chain)",
                  ["camera"], registry=registry),
            Gauge("monitor_reaction_time_configured_seconds", "T_r that S_p was computed with",
                  registry=registry),
            Gauge("monitor_reaction_budget_exceeded", "1 when the measured budget exceeds T_r",
                  ["camera"], registry=registry))


class ReactionSink:
    """A driver sink after the service's own: times each processed frame's capture ->
    command (the command is published by then), and every ``period_s`` compares the live p99
    budget with T_r: status field, gauges, alerts through ``alert``."""

    def __init__(self, budget: MeasuredBudget, watch: ReactionWatch,
                 alert: Callable[[Alert], None], update_status: Callable[..., None],
                 registry=None, period_s: float = 5.0,
                 start: Mapping[str, Verdict] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.budget = budget
        self.watch = watch
        self.alert = alert
        self.update_status = update_status
        self.period_s = period_s
        self.clock = clock
        self.verdicts: dict[str, Verdict] = dict(start or {})
        self.next_check = clock() + period_s
        self.gauges = reaction_gauges(registry) if registry is not None else None
        self._publish()

    def on_step(self, step) -> None:
        now = self.clock()
        frame = step.frame
        if frame is not None and step.stalled_s is None:  # a stalled step's command is new
            self.budget.add(frame.info.camera_id, frame.info.capture_time, now)
        if now >= self.next_check:
            self.next_check = now + self.period_s
            self.check(now)

    def check(self, now: float) -> None:
        verdicts, alerts = self.watch.update(self.budget.budgets(), now)
        self.verdicts.update(verdicts)
        for alert in alerts:
            self.alert(alert)
        self._publish()

    def _publish(self) -> None:
        self.update_status(reaction_budget=status_of(self.verdicts, self.watch.configured_s))
        if self.gauges is not None:
            measured, configured, exceeded = self.gauges
            configured.set(self.watch.configured_s)
            for cam, v in self.verdicts.items():
                measured.labels(cam).set(v.measured.total_s)
                exceeded.labels(cam).set(1.0 if v.exceeded else 0.0)

    def close(self) -> None:
        pass
