"""OTUS tool-tracker pose stream: UDP codec, plausibility checks, Zenoh pose samples.

The OTUS tracker (ZČU Plzeň tracker report, 2018) sends one UDP datagram per pose: 23 little-
endian IEEE-754 doubles, 184 bytes, in this order: device id, timestamp, position xyz, linear
velocity xyz, linear acceleration xyz, orientation quaternion xyzw, angular velocity xyz,
angular acceleration xyz, button 1, button 2 (table: docs/otus.md). Units are taken as SI:
metres, seconds, radians (the vendor's OpenVR-based software works in metres); the frame is the
tracker's own frame, before the tool mounting offset is applied.

The tracker's measurements contain unflagged "nonsense values", so nothing is trusted:
``PoseValidator`` rejects a sample with a named reason (``REJECT_REASONS``) and the pipeline
stays on the last accepted one; when that gets older than ``pose_timeout`` the policy STOPs.

Zenoh pose sample on ``<prefix>tracker/pose``: UTF-8 JSON, one object per sample::

    {"schema": "workcell.tracker.pose/1", "seq": 17, "source": "otus", "bridge": "<instance>",
     "recv_mono": 1234.5, "recv_wall": 1.7e9, "device_id": 1.0, "t_tracker": 12.0025,
     "position_m": [x, y, z], "velocity_m_s": [...], "acceleration_m_s2": [...],
     "quaternion_xyzw": [x, y, z, w], "angular_velocity_rad_s": [...],
     "angular_acceleration_rad_s2": [...], "buttons": [b1, b2]}

The bridge publishes only samples its own checks accept; rejected packets are counted, raise a
rate-limited ``pose_rejected`` alert and are published for diagnosis on
``<prefix>tracker/pose/rejected`` (``{"reason", "message", "packet_hex", ...}``). The service
checks every sample again (``PoseSubscriber``): anything may publish on a key.
"""

from __future__ import annotations

import dataclasses
import json
import math
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

from monitor.errors import ConfigError
from monitor.pose.otus import (
    OtusSample,
    PacketError,
    Vec3,
    decode_otus,
    sample_from_values,
)
from monitor.pose.tool_motion import MotionLimits, ToolMotion, ToolSpeed, estimate_tool_speed
from monitor.pose.tracker_noise import TrackerConfig
from monitor.pose.tracker_time import TrackerClock, TrackerClockConfig

POSE_SCHEMA = "workcell.tracker.pose/1"

@dataclass(frozen=True)
class PoseLimits:
    """Plausibility limits for a hand-guided tool. Metres, seconds, radians.

    The tolerances absorb the tracker's measured errors (the tracker report: up to ~25 mm and ~3° in
    dynamic motion, ~40 mm/s velocity error) so that jitter at 400 Hz does not read as a jump;
    ``noise`` (the declared precision) raises them to what two noisy readings of a tool at rest
    may differ by (``position_allowance_m``, ``angle_allowance_rad``).
    """

    quaternion_tolerance: float = 0.02  # allowed | |q| - 1 |
    max_speed_m_s: float = 4.0
    max_accel_m_s2: float = 60.0
    max_angular_speed_rad_s: float = 4 * math.pi
    position_jitter_m: float = 0.025
    velocity_jitter_m_s: float = 0.08
    angle_jitter_rad: float = math.radians(3.0)
    bounds_min_m: Vec3 | None = None  # tracking volume, e.g. (-2.5, -2.5, 0.0)
    bounds_max_m: Vec3 | None = None
    resync_samples: int = 5  # consistent samples in a row after a jump that are accepted again
    noise: TrackerConfig = field(default_factory=TrackerConfig)

    @property
    def position_allowance_m(self) -> float:
        return max(self.position_jitter_m, self.noise.span_m)

    @property
    def angle_allowance_rad(self) -> float:
        return max(self.angle_jitter_rad, self.noise.span_rad)

    def __post_init__(self) -> None:
        for name in ("quaternion_tolerance", "max_speed_m_s", "max_accel_m_s2",
                     "max_angular_speed_rad_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"pose.{name}: must be a positive number, got {value!r}")
        if (self.bounds_min_m is None) != (self.bounds_max_m is None):
            raise ConfigError("pose.bounds_min_m/bounds_max_m: give both or neither")
        if self.resync_samples < 1:
            raise ConfigError("pose.resync_samples: must be >= 1")


@dataclass(frozen=True)
class Rejection:
    reason: str
    message: str


def _norm(v: tuple[float, ...]) -> float:
    return math.sqrt(sum(x * x for x in v))


def _sub(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, ...]:
    return tuple(x - y for x, y in zip(a, b, strict=True))


def check_sample(sample: OtusSample, limits: PoseLimits) -> Rejection | None:
    """Checks of one sample on its own: finite values, unit quaternion, bounds, reported rates."""
    if not all(math.isfinite(x) for x in sample.values()):
        return Rejection("non_finite", "sample contains NaN or infinity")
    qn = _norm(sample.quaternion_xyzw)
    if abs(qn - 1.0) > limits.quaternion_tolerance:
        return Rejection("quaternion_norm", f"|q| = {qn:.4f}, not 1 ± "
                         f"{limits.quaternion_tolerance}")
    if limits.bounds_min_m is not None and limits.bounds_max_m is not None and not all(
        lo <= x <= hi for x, lo, hi in zip(sample.position_m, limits.bounds_min_m,
                                           limits.bounds_max_m, strict=True)
    ):
        return Rejection("out_of_bounds", f"position {sample.position_m} m outside the volume")
    speed = _norm(sample.velocity_m_s)
    if speed > limits.max_speed_m_s:
        return Rejection("speed", f"reported speed {speed:.2f} m/s > {limits.max_speed_m_s}")
    accel = _norm(sample.acceleration_m_s2)
    if accel > limits.max_accel_m_s2:
        return Rejection("acceleration", f"reported acceleration {accel:.1f} m/s² > "
                         f"{limits.max_accel_m_s2}")
    omega = _norm(sample.angular_velocity_rad_s)
    if omega > limits.max_angular_speed_rad_s:
        return Rejection("angular_speed", f"reported angular speed {omega:.2f} rad/s > "
                         f"{limits.max_angular_speed_rad_s:.2f}")
    return None


def check_step(prev: OtusSample, sample: OtusSample, limits: PoseLimits) -> Rejection | None:
    """Checks of a sample against the previous accepted one: time order and implied rates."""
    dt = sample.timestamp - prev.timestamp
    if dt < 0:
        return Rejection("timestamp_backwards", f"timestamp {sample.timestamp} < previous "
                         f"{prev.timestamp}")
    if dt == 0:
        return Rejection("timestamp_repeat", f"timestamp {sample.timestamp} repeats")
    jitter = limits.position_allowance_m
    jump = max(0.0, _norm(_sub(sample.position_m, prev.position_m)) - jitter)
    if jump / dt > limits.max_speed_m_s:
        return Rejection("speed", f"position jumped {jump + jitter:.3f} m in "
                         f"{dt * 1000:.1f} ms (> {limits.max_speed_m_s} m/s)")
    dv = max(0.0, _norm(_sub(sample.velocity_m_s, prev.velocity_m_s)) - limits.velocity_jitter_m_s)
    if dv / dt > limits.max_accel_m_s2:
        return Rejection("acceleration", f"velocity changed {dv:.2f} m/s in {dt * 1000:.1f} ms "
                         f"(> {limits.max_accel_m_s2} m/s²)")
    q0 = _unit(prev.quaternion_xyzw)
    q1 = _unit(sample.quaternion_xyzw)
    dot = min(1.0, abs(sum(a * b for a, b in zip(q0, q1, strict=True))))
    turn = 2.0 * math.acos(dot)
    if max(0.0, turn - limits.angle_allowance_rad) / dt > limits.max_angular_speed_rad_s:
        return Rejection("angular_speed", f"orientation jumped {math.degrees(turn):.1f}° in "
                         f"{dt * 1000:.1f} ms")
    return None


def _unit(q: tuple[float, ...]) -> tuple[float, ...]:
    n = _norm(q)
    return tuple(x / n for x in q)


@dataclass
class PoseValidator:
    """Stateful plausibility check of a pose stream (not thread-safe; one per stream).

    After a rejected jump the stream is re-synchronised only when ``resync_samples`` samples in a
    row agree with each other (a real re-acquisition), never on one outlier.
    """

    limits: PoseLimits = field(default_factory=PoseLimits)
    previous: OtusSample | None = None
    rejected: Counter = field(default_factory=Counter)
    accepted: int = 0
    resyncs: int = 0
    _candidate: OtusSample | None = None
    _candidate_run: int = 0

    def check(self, sample: OtusSample) -> Rejection | None:
        """None when accepted (and remembered as the previous sample), else the rejection."""
        bad = check_sample(sample, self.limits)
        if bad is None and self.previous is not None:
            bad = check_step(self.previous, sample, self.limits)
            if bad is not None and bad.reason != "timestamp_repeat":
                bad = self._try_resync(sample, bad)
        if bad is not None:
            self.rejected[bad.reason] += 1
            return bad
        self.previous = sample
        self.accepted += 1
        self._candidate, self._candidate_run = None, 0
        return None

    def reject_packet(self, error: PacketError) -> Rejection:
        """Count a packet that could not even be decoded."""
        self.rejected[error.reason] += 1
        return Rejection(error.reason, str(error))

    def _try_resync(self, sample: OtusSample, bad: Rejection) -> Rejection | None:
        if self._candidate is not None and check_step(self._candidate, sample, self.limits) is None:
            self._candidate_run += 1
        else:
            self._candidate_run = 1
        self._candidate = sample
        if self._candidate_run >= self.limits.resync_samples:
            self.resyncs += 1
            return None
        return bad


# --- Zenoh pose samples -------------------------------------------------------------------------


def pose_to_json(sample: OtusSample, *, seq: int, recv_mono: float, recv_wall: float,
                 bridge: str = "", source: str = "otus") -> bytes:
    """The ``tracker/pose`` payload (schema in the module docstring)."""
    return json.dumps({
        "schema": POSE_SCHEMA, "seq": seq, "source": source, "bridge": bridge,
        "recv_mono": recv_mono, "recv_wall": recv_wall, "device_id": sample.device_id,
        "t_tracker": sample.timestamp, "position_m": list(sample.position_m),
        "velocity_m_s": list(sample.velocity_m_s),
        "acceleration_m_s2": list(sample.acceleration_m_s2),
        "quaternion_xyzw": list(sample.quaternion_xyzw),
        "angular_velocity_rad_s": list(sample.angular_velocity_rad_s),
        "angular_acceleration_rad_s2": list(sample.angular_acceleration_rad_s2),
        "buttons": [sample.button1, sample.button2],
    }, allow_nan=False).encode()


MAX_POSE_JSON_BYTES = 4096  # a real sample is ~600 bytes
MAX_NUMBER_CHARS = 40  # digits of one JSON number (a double needs at most ~25)
MAX_MAGNITUDE = 1e12  # |value| of any number in a sample (metres, s, rad; Unix time fits)


def _bounded_number(text: str) -> float:
    """JSON number hook: refuses long digit strings and huge or non-finite values before
    Python turns them into a 400-digit int (whose float() would raise OverflowError)."""
    if len(text) > MAX_NUMBER_CHARS:
        raise ValueError(f"a number has {len(text)} characters (at most {MAX_NUMBER_CHARS})")
    value = float(text)
    if not (math.isfinite(value) and abs(value) <= MAX_MAGNITUDE):
        raise ValueError(f"number {text} is out of range (|x| <= {MAX_MAGNITUDE:g})")
    return value


def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number a pose may contain")


def pose_from_json(payload: bytes) -> tuple[OtusSample, dict]:
    """Parse a ``tracker/pose`` payload; returns the sample and the whole object.

    Bounded before anything is trusted: at most ``MAX_POSE_JSON_BYTES`` bytes, numbers of at
    most ``MAX_NUMBER_CHARS`` characters and magnitude ``MAX_MAGNITUDE``, no NaN/Infinity.
    Raises ``PacketError("malformed")`` with a one-line message on any fault."""
    try:
        if len(payload) > MAX_POSE_JSON_BYTES:
            raise ValueError(f"payload has {len(payload)} bytes (at most {MAX_POSE_JSON_BYTES})")
        body = json.loads(payload, parse_int=_bounded_number, parse_float=_bounded_number,
                          parse_constant=_no_constant)
        if not isinstance(body, dict):
            raise ValueError("not a JSON object")
        if body.get("schema") != POSE_SCHEMA:
            raise ValueError(f"schema {str(body.get('schema'))[:40]!r}")
        values = [_number(body["device_id"]), _number(body["t_tracker"])]
        for key, n in (("position_m", 3), ("velocity_m_s", 3), ("acceleration_m_s2", 3),
                       ("quaternion_xyzw", 4), ("angular_velocity_rad_s", 3),
                       ("angular_acceleration_rad_s2", 3), ("buttons", 2)):
            raw = body[key]
            if not isinstance(raw, list) or len(raw) != n:
                raise ValueError(f"{key} is not a list of {n} numbers")
            values += [_number(x) for x in raw]
    except (ValueError, KeyError, TypeError, AttributeError, OverflowError,
            RecursionError) as exc:
        text = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        raise PacketError("malformed", f"pose sample is not {POSE_SCHEMA}: {text}") from None
    return sample_from_values(values), body


def _number(x: object) -> float:
    """A JSON number as float (bools are not numbers here)."""
    if isinstance(x, bool) or not isinstance(x, int | float):
        raise ValueError(f"{str(x)[:40]!r} is not a number")
    return float(x)


@dataclass(frozen=True)
class PoseReading:
    """The newest accepted pose. ``received`` is on the monotonic clock of this process;
    ``history`` the accepted samples of the last ``MotionLimits.history_s`` (oldest first,
    ending with ``sample``) for the measured tool speed."""

    sample: OtusSample
    received: float
    age: float  # seconds since ``received`` at the time of the query
    history: tuple[OtusSample, ...] = ()
    motion_limits: MotionLimits = field(default_factory=MotionLimits)
    clock_fault: object | None = None  # monitor.types.Fault: tracker time disagrees (pose_time)

    def tool_speed(self, tool_points: object = None, unknown_mps: float = 0.0) -> ToolSpeed:
        """Speed of the fastest tool point to use for S_p (``estimate_tool_speed``); the
        service passes ``speed_mps`` as ``tool_speed_mps`` and ``fault`` as an extra fault.
        While the tracker's time is in doubt the history is empty (the speed falls back to
        ``unknown_mps``) and ``fault`` is the clock's."""
        history = self.history or (self.sample,)
        speed = estimate_tool_speed(history, tool_points, self.motion_limits, unknown_mps)
        if self.clock_fault is not None:
            speed = dataclasses.replace(speed, fault=self.clock_fault)
        return speed

    def tool_pose(self):
        """As ``monitor.geometry.ToolPose`` (time = receive time, monotonic s)."""
        from monitor.geometry import ToolPose  # geometry pulls numpy; pose stays light

        return ToolPose(self.sample.position_m, self.sample.quaternion_xyzw, self.received)


class PoseSubscriber:
    """Subscribes to ``<prefix>tracker/pose`` on an open Zenoh session and keeps the newest
    accepted sample. Re-checks every sample with its own ``PoseValidator``.

    Use as a context manager (undeclares the subscriber on exit); ``latest()`` and
    ``pose_time()`` are what the service feeds to the policy. Every sample's tracker time is
    checked against its receive time (``monitor.pose.tracker_time``): while it disagrees the speed
    history stays empty and ``latest().clock_fault`` is a ``pose_implausible`` fault.
    """

    def __init__(self, session, key: str, limits: PoseLimits | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 on_reject: Callable[[Rejection], None] | None = None,
                 motion: MotionLimits | None = None,
                 tracker_clock: TrackerClockConfig | None = None,
                 tracker: TrackerConfig | None = None) -> None:
        # ``tracker``: the declared precision the default limits allow for (``[tracker]``)
        noise = tracker or TrackerConfig()
        self._session = session
        self._motion = ToolMotion(motion or MotionLimits(noise=noise))
        self._tracker_clock = TrackerClock(tracker_clock or TrackerClockConfig())
        self._key = key
        self._clock = clock
        self._validator = PoseValidator(limits or PoseLimits(noise=noise))
        self._lock = threading.Lock()
        self._latest: tuple[OtusSample, float] | None = None
        self._rejections: list[Rejection] = []
        self._on_reject = on_reject
        self._sub = None

    def __enter__(self) -> PoseSubscriber:
        self._sub = self._session.declare_subscriber(self._key, self._on_sample)
        return self

    def __exit__(self, *exc) -> None:
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None

    def _on_sample(self, zsample) -> None:
        self.receive(zsample.payload.to_bytes(), self._clock())

    def receive(self, payload: bytes, now: float) -> None:
        """One ``tracker/pose`` payload received at ``now`` (this process's clock)."""
        try:
            sample, _ = pose_from_json(payload)
        except PacketError as err:
            with self._lock:
                bad = self._validator.reject_packet(err)
                self._rejections.append(bad)
        else:
            with self._lock:
                # every decoded sample, accepted or not: a step back is seen at the step
                time_fault = self._tracker_clock.check(sample.timestamp, now)
                if time_fault is not None:
                    self._motion.clear()  # no speed window may span the tracker's jump
                bad = self._validator.check(sample)
                if bad is None:
                    self._latest = (sample, now)
                    if time_fault is None:
                        self._motion.add(sample)
                else:
                    self._rejections.append(bad)
        if bad is not None and self._on_reject is not None:
            self._on_reject(bad)

    def latest(self) -> PoseReading | None:
        with self._lock:
            if self._latest is None:
                return None
            sample, received = self._latest
            history = self._motion.history()
            clock_fault = self._tracker_clock.fault
        return PoseReading(sample, received, self._clock() - received, history,
                           self._motion.limits, clock_fault)

    def pose_time(self) -> float | None:
        """Receive time of the newest accepted sample (for ``PolicyInputs.pose_time``)."""
        with self._lock:
            return None if self._latest is None else self._latest[1]

    def drain_rejections(self) -> list[Rejection]:
        with self._lock:
            out, self._rejections = self._rejections, []
        return out

    def stats(self) -> dict:
        with self._lock:
            v = self._validator
            return {"accepted": v.accepted, "rejected": dict(v.rejected), "resyncs": v.resyncs,
                    "clock_faults": self._tracker_clock.faults}


# --- UDP bridge -------------------------------------------------------------------------------


def parse_host_port(text: str, default_port: int = 5400) -> tuple[str, int]:
    """``"127.0.0.1:5400"`` -> ("127.0.0.1", 5400); raises ConfigError."""
    host, _, port = text.rpartition(":")
    if not host:
        host, port = text, str(default_port)
    try:
        return host.strip("[]"), int(port)
    except ValueError:
        raise ConfigError(f"--listen {text!r}: expected HOST:PORT") from None


class OtusBridge:
    """Reads OTUS datagrams from a UDP socket and republishes them on Zenoh.

    ``publish(key_suffix, payload)`` and ``alert(rejection)`` are given by the caller (the CLI
    wires them to a ``SafetyBus``-like publisher); the loop runs until ``stop`` is set.
    """

    def __init__(self, sock: socket.socket, publish: Callable[[str, bytes], None],
                 alert: Callable[[Rejection], None], limits: PoseLimits | None = None,
                 instance: str = "", clock: Callable[[], float] = time.monotonic,
                 pose_timeout: float = 0.1) -> None:
        self.sock = sock
        self.publish = publish
        self.alert = alert
        self.validator = PoseValidator(limits or PoseLimits())
        self.instance = instance
        self.clock = clock
        self.pose_timeout = pose_timeout
        self.seq = 0
        self.packets = 0
        self.silences = 0
        self._last_packet: float | None = None
        self._silent = False

    def check_silence(self) -> Rejection | None:
        """Alert once per gap when the stream, once started, is silent beyond pose_timeout."""
        if self._last_packet is None or self._silent:
            return None
        gap = self.clock() - self._last_packet
        if gap <= self.pose_timeout:
            return None
        self._silent = True
        self.silences += 1
        bad = Rejection("silence", f"no OTUS packet for {gap:.2f} s "
                        f"(pose_timeout {self.pose_timeout} s)")
        self.alert(bad)
        return bad

    def handle(self, packet: bytes) -> Rejection | None:
        """Decode, check and publish one datagram."""
        self.packets += 1
        now, wall = self.clock(), time.time()
        self._last_packet, self._silent = now, False
        try:
            sample = decode_otus(packet)
        except PacketError as err:
            bad = self.validator.reject_packet(err)
        else:
            bad = self.validator.check(sample)
            if bad is None:
                self.seq += 1
                self.publish("tracker/pose", pose_to_json(
                    sample, seq=self.seq, recv_mono=now, recv_wall=wall, bridge=self.instance))
                return None
        self.publish("tracker/pose/rejected", json.dumps({
            "reason": bad.reason, "message": bad.message, "recv_mono": now, "recv_wall": wall,
            "bridge": self.instance, "packet_hex": packet[:256].hex(),
        }).encode())
        self.alert(bad)
        return bad

    def run(self, stop: threading.Event) -> None:
        self.sock.settimeout(max(0.01, self.pose_timeout / 2))
        while not stop.is_set():
            try:
                packet = self.sock.recv(2048)
            except TimeoutError:
                self.check_silence()
                continue
            self.handle(packet)
            self.check_silence()
