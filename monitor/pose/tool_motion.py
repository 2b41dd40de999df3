"""Tool speed measured from the OTUS pose stream itself (issue 11).

The tracker's velocity field is not trusted: the speed of every tool point is measured from the
positions and orientations over a window of accepted samples, rotation included, and compared
with the reported rates (a disagreement is a STOP fault ``pose_implausible``). The speed used
for S_p is the larger of measured and reported. docs/separation.md explains the numbers.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass, field

from monitor.errors import ConfigError
from monitor.pose.otus import OtusSample
from monitor.pose.tracker_noise import TrackerConfig

Vec3 = tuple[float, float, float]


def _norm(v: tuple[float, ...]) -> float:
    return math.sqrt(sum(x * x for x in v))


def _sub(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, ...]:
    return tuple(x - y for x, y in zip(a, b, strict=True))


def _unit(q: tuple[float, ...]) -> tuple[float, ...]:
    n = _norm(q)
    return tuple(x / n for x in q)


@dataclass(frozen=True)
class MotionLimits:
    """How the tool speed is measured from the stream and when the reported rates are not
    believed. Metres, seconds, radians.

    ``window_s``: the speed is measured between the newest sample and ones at least this much
    older (tracker time): at 400 Hz two consecutive samples are 2.5 ms apart and ±1 mm of
    tracker precision alone would read as 0.8 m/s. Every window from ``window_s`` up to the
    whole history counts (at most ``windows`` of them, spread evenly) and the largest speed
    wins, so no single window length can alias with the motion. ``max_samples`` bounds the
    history in samples whatever the timestamps say. ``speed_tolerance_m_s`` and
    ``relative_tolerance``: how far the reported mean velocity over the window may differ from
    the displacement over it; ``angular_tolerance_rad_s`` the same for the rotation (both are
    the error of the reported rates). ``noise``: the tracker's declared precision; the two
    poses at a window's ends may differ by its span (``TrackerConfig.span_m``, ``span_rad``)
    from noise alone, so the tolerances over a window of ``dt`` grow by ``span / dt``.
    """

    window_s: float = 0.05
    history_s: float = 0.5
    speed_tolerance_m_s: float = 0.15
    angular_tolerance_rad_s: float = 0.5
    relative_tolerance: float = 0.2
    max_samples: int = 1000  # 0.5 s at 2 kHz
    windows: int = 32
    noise: TrackerConfig = field(default_factory=TrackerConfig)

    def __post_init__(self) -> None:
        for name in ("window_s", "history_s", "speed_tolerance_m_s", "angular_tolerance_rad_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"pose.{name}: must be a positive number, got {value!r}")
        if self.history_s < self.window_s:
            raise ConfigError("pose.history_s: must be at least window_s")
        if not (math.isfinite(self.relative_tolerance) and self.relative_tolerance >= 0):
            raise ConfigError("pose.relative_tolerance: must be >= 0")
        if self.max_samples < 2 or self.windows < 1:
            raise ConfigError("pose.max_samples: must be >= 2 and pose.windows >= 1")


@dataclass(frozen=True)
class ToolSpeed:
    """The tool speed to use for S_p and how it was found (m/s).

    ``speed_mps`` = the largest of ``measured_mps`` (from the positions and orientations of
    the stream over ``MotionLimits.window_s``, every tool point, rotation included) and
    ``reported_mps`` (the newest sample's velocity and angular velocity at every tool point);
    with too short a history the fallback speed takes the measured one's place. ``fault`` is a
    STOP ``pose_implausible`` fault when the reported rates disagree with the measured ones.
    """

    speed_mps: float
    measured_mps: float | None
    reported_mps: float
    fault: object | None = None  # monitor.types.Fault


def _rotation(q: tuple[float, ...]) -> tuple[tuple[float, float, float], ...]:
    x, y, z, w = _unit(q)
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
            (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
            (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)))


def _rotate(m: tuple[tuple[float, float, float], ...], r: tuple[float, ...]) -> Vec3:
    return (m[0][0] * r[0] + m[0][1] * r[1] + m[0][2] * r[2],
            m[1][0] * r[0] + m[1][1] * r[1] + m[1][2] * r[2],
            m[2][0] * r[0] + m[2][1] * r[1] + m[2][2] * r[2])


def _cross(a: tuple[float, ...], b: tuple[float, ...]) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _rotation_vector(q0: tuple[float, ...], q1: tuple[float, ...]) -> Vec3:
    """Axis * angle of the rotation from q0 to q1, in the reference frame (q1 * conj(q0))."""
    x0, y0, z0, w0 = _unit(q0)
    x1, y1, z1, w1 = _unit(q1)
    # q = q1 * conj(q0)
    w = w1 * w0 + x1 * x0 + y1 * y0 + z1 * z0
    x = -w1 * x0 + x1 * w0 - y1 * z0 + z1 * y0
    y = -w1 * y0 + y1 * w0 - z1 * x0 + x1 * z0
    z = -w1 * z0 + z1 * w0 - x1 * y0 + y1 * x0
    if w < 0:
        x, y, z, w = -x, -y, -z, -w
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-12:
        return (0.0, 0.0, 0.0)
    angle = 2.0 * math.atan2(n, w)
    return (x / n * angle, y / n * angle, z / n * angle)


def _point_speeds(sample: OtusSample, points: list[Vec3]) -> float:
    """Largest reported speed of the tool points: |v + w x (R r)| (w in the reference frame,
    as OpenVR reports it)."""
    m = _rotation(sample.quaternion_xyzw)
    best = 0.0
    for r in points:
        arm = _rotate(m, r)
        rot = _cross(sample.angular_velocity_rad_s, arm)
        best = max(best, _norm(tuple(v + w for v, w in zip(sample.velocity_m_s, rot,
                                                             strict=True))))
    return best


def estimate_tool_speed(history: tuple[OtusSample, ...] | list[OtusSample],
                        tool_points: object = None, limits: MotionLimits | None = None,
                        unknown_mps: float = 0.0) -> ToolSpeed:
    """The speed of the fastest tool point from accepted samples (oldest first), tracker frame.

    ``tool_points`` are (N, 3) points of the tool in the tracker body frame, metres (for a
    zone file: ``monitor.zones.separation.tool_points_in_tracker(cell.prepared)``); None means
    the tracker origin only. Pure: the same history always gives the same answer.
    """
    from monitor.types import Fault  # types is light; keep the import local like geometry

    lim = limits or MotionLimits()
    if not history:
        return ToolSpeed(max(unknown_mps, 0.0), None, 0.0)
    pts: list[Vec3] = [(0.0, 0.0, 0.0)]
    if tool_points is not None:
        pts += [tuple(float(c) for c in p) for p in tool_points]  # type: ignore[union-attr]
    new = history[-1]
    reported = _point_speeds(new, pts)
    # the newest sample at least window_s older; every older one is a longer window
    last = next((k for k in range(len(history) - 2, -1, -1)
                 if new.timestamp - history[k].timestamp >= lim.window_s), None)
    if last is None:
        return ToolSpeed(max(reported, unknown_mps), None, reported)
    m1 = _rotation(new.quaternion_xyzw)
    ends = [tuple(p + q for p, q in zip(new.position_m, _rotate(m1, r), strict=True))
            for r in pts]
    stride = max(1, -(-(last + 1) // lim.windows))
    measured, best = -1.0, history[last]
    for k in range(last, -1, -stride):
        old = history[k]
        dt = new.timestamp - old.timestamp
        if dt < lim.window_s:  # a history whose time is not in order: not a window
            continue
        m0 = _rotation(old.quaternion_xyzw)
        for r, b in zip(pts, ends, strict=True):
            a = tuple(p + q for p, q in zip(old.position_m, _rotate(m0, r), strict=True))
            speed = _norm(_sub(b, a)) / dt
            if speed > measured:
                measured, best = speed, old
    old = history[last]
    fault = _plausibility_fault(history, old, new, new.timestamp - old.timestamp, lim, Fault)
    if fault is None and best is not old:
        # the fastest window against the reported velocity too (linear only: a rotation
        # vector over a long window wraps at pi and is no mean of the angular velocity)
        fault = _plausibility_fault(history, best, new, new.timestamp - best.timestamp, lim,
                                    Fault, angular=False)
    calm = _calm_start(history, new, lim)
    if fault is None and calm is not old:
        # over window_s the tracker's noise allows a lot (1 degree: 3.5 rad/s over 50 ms), a
        # jump shows there; a steady lie about the rotation shows over a window long enough
        # for the noise to fall under angular_tolerance_rad_s
        fault = _plausibility_fault(history, calm, new, new.timestamp - calm.timestamp, lim,
                                    Fault, linear=False)
    return ToolSpeed(max(measured, reported), measured, reported, fault)


def _calm_start(history, new: OtusSample, lim: MotionLimits) -> OtusSample:
    """The newest sample old enough that the orientation noise over the window to ``new``
    stays under ``angular_tolerance_rad_s`` (the oldest one while the history is shorter)."""
    need = max(lim.window_s, lim.noise.span_rad / lim.angular_tolerance_rad_s)
    for s in reversed(history):
        if new.timestamp - s.timestamp >= need:
            return s
    return history[0]


def _turned(span: list[OtusSample]) -> Vec3:
    """The rotation over ``span`` as the sum of the rotation vectors between its samples:
    unlike the rotation vector between its ends it does not wrap at pi over a long window,
    and their noise cancels pairwise as the ends' would."""
    total = [0.0, 0.0, 0.0]
    for a, b in itertools.pairwise(span):
        step = _rotation_vector(a.quaternion_xyzw, b.quaternion_xyzw)
        for k in range(3):
            total[k] += step[k]
    return (total[0], total[1], total[2])


def _plausibility_fault(history, old: OtusSample, new: OtusSample, dt: float,
                        lim: MotionLimits, fault_type, angular: bool = True,
                        linear: bool = True) -> object | None:
    """Mean reported velocity and angular velocity over [old, new] (trapezoid rule) against
    the displacement and rotation over the same span."""
    span = [s for s in history if old.timestamp <= s.timestamp <= new.timestamp]
    v_mean = [0.0, 0.0, 0.0]
    w_mean = [0.0, 0.0, 0.0]
    for a, b in itertools.pairwise(span):
        h = (b.timestamp - a.timestamp) / dt / 2.0
        for k in range(3):
            v_mean[k] += h * (a.velocity_m_s[k] + b.velocity_m_s[k])
            w_mean[k] += h * (a.angular_velocity_rad_s[k] + b.angular_velocity_rad_s[k])
    v_meas = tuple(x / dt for x in _sub(new.position_m, old.position_m))
    w_meas = tuple(x / dt for x in _turned(span))
    dv = _norm(_sub(tuple(v_mean), v_meas))
    dw = _norm(_sub(tuple(w_mean), w_meas))
    # the poses at both ends carry the tracker's noise: a tool at rest "moves" by up to the
    # noise span over the window (issue 29: 1 degree of noise read as 0.8 rad/s over 50 ms)
    v_tol = (lim.speed_tolerance_m_s + lim.noise.span_m / dt
             + lim.relative_tolerance * max(_norm(v_meas), _norm(tuple(v_mean))))
    w_tol = (lim.angular_tolerance_rad_s + lim.noise.span_rad / dt
             + lim.relative_tolerance * max(_norm(w_meas), _norm(tuple(w_mean))))
    if linear and dv > v_tol:
        return fault_type("pose_implausible",
                          f"tracker reports {_norm(tuple(v_mean)):.2f} m/s but its positions "
                          f"moved at {_norm(v_meas):.2f} m/s over {dt * 1000:.0f} ms", True,
                          "pose")
    if angular and dw > w_tol:
        return fault_type("pose_implausible",
                          f"tracker reports {_norm(tuple(w_mean)):.2f} rad/s but its "
                          f"orientation turned at {_norm(w_meas):.2f} rad/s over "
                          f"{dt * 1000:.0f} ms", True, "pose")
    return None


class ToolMotion:
    """Keeps the accepted samples of the last ``history_s`` (tracker time), at most
    ``max_samples`` of them, for ``estimate_tool_speed``. Not thread-safe: ``PoseSubscriber``
    calls it under its lock."""

    def __init__(self, limits: MotionLimits | None = None) -> None:
        self.limits = limits or MotionLimits()
        self._samples: deque[OtusSample] = deque(maxlen=self.limits.max_samples)

    def add(self, sample: OtusSample) -> None:
        self._samples.append(sample)
        cut = sample.timestamp - self.limits.history_s
        while len(self._samples) > 1 and self._samples[1].timestamp <= cut:
            self._samples.popleft()

    def clear(self) -> None:
        """Forget the history (the tracker's time base changed: no window may span it)."""
        self._samples.clear()

    def history(self) -> tuple[OtusSample, ...]:
        return tuple(self._samples)

    def tool_speed(self, tool_points: object = None, unknown_mps: float = 0.0) -> ToolSpeed:
        return estimate_tool_speed(tuple(self._samples), tool_points, self.limits, unknown_mps)
