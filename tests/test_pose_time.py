"""Tracker time checked against receive time (issue 20, part 6).

Each attack of the finding is a real pose stream: OTUS samples as ``tracker/pose`` JSON, fed to
the service's ``PoseSubscriber`` with the receive time of every payload (``receive``, what its
Zenoh callback calls), or over real Zenoh on 127.0.0.1. What counts is what the service uses:
``latest().tool_speed(...)``: a ``pose_implausible`` fault or a correct speed, never ~0.
"""

from __future__ import annotations

import math
import random
import time

import pytest

from monitor.bus.session import BusConfig, BusKeys, open_session
from monitor.config import parse_config
from monitor.errors import ConfigError
from monitor.pose.otus import OtusSample
from monitor.pose.stream import PoseSubscriber, pose_to_json
from monitor.pose.tool_motion import MotionLimits
from monitor.pose.tracker_time import TrackerClock, TrackerClockConfig
from tests.helpers import free_port

HZ = 400.0
ZERO = (0.0, 0.0, 0.0)
UNKNOWN = 1.5  # robot_speed_default_mps: what the service uses without a measured speed
CIRCLE_MPS = 2 * math.pi * 0.2  # 1 Hz on a 0.2 m radius: 1.2566 m/s


def pose(t: float, pos, vel=ZERO) -> OtusSample:
    return OtusSample(1.0, t, tuple(pos), tuple(vel), ZERO, (0.0, 0.0, 0.0, 1.0), ZERO, ZERO)


def line(real_t: float, v: float = 1.0):
    """Position and velocity of a tool moving along x at v m/s at real time real_t."""
    return (0.2 + v * real_t, 0.1, 1.0), (v, 0.0, 0.0)


def circle(real_t: float, radius: float = 0.2, hz: float = 1.0):
    """A tool circling about (0.5, 0, 1): position and its true velocity."""
    w = 2 * math.pi * hz
    pos = (0.5 + radius * math.cos(w * real_t), radius * math.sin(w * real_t), 1.0)
    vel = (-radius * w * math.sin(w * real_t), radius * w * math.cos(w * real_t), 0.0)
    return pos, vel


class Stream:
    """The service's pose subscriber fed with JSON payloads at given receive times."""

    def __init__(self, config: TrackerClockConfig | None = None) -> None:
        self.sub = PoseSubscriber(None, "workcell/t/tracker/pose", tracker_clock=config)
        self.seq = 0

    def send(self, sample: OtusSample, received: float):
        self.seq += 1
        self.sub.receive(pose_to_json(sample, seq=self.seq, recv_mono=received,
                                      recv_wall=1.7e9 + received), received)
        return self.sub.latest()


def speed_of(reading):
    return reading.tool_speed(unknown_mps=UNKNOWN)


def is_time_fault(speed) -> bool:
    return (speed.fault is not None and speed.fault.name == "pose_implausible"
            and speed.fault.stop and "tracker time" in speed.fault.reason)


# ------------------------------------------------------------------------------- the attacks


def test_timestamps_in_milliseconds_are_a_fault_from_the_second_sample():
    """The finding: 300 of 300 samples at ~0.001 m/s. Tool at 1 m/s, time and velocity in ms."""
    stream = Stream()
    speeds = []
    for i in range(300):
        real = i / HZ
        pos, _ = line(real)
        sample = pose(1000.0 * (3.0 + real), pos, (0.001, 0.0, 0.0))  # ms and m/ms
        speeds.append(speed_of(stream.send(sample, 50.0 + real + 0.001)))
    assert all(is_time_fault(s) for s in speeds[1:])
    assert "not in seconds" in speeds[1].fault.reason
    assert stream.sub.latest().history == ()  # no window over a time base in doubt


def test_a_one_second_jump_is_a_fault_until_the_clock_is_learned_again():
    """The finding: after +1 s, 13 samples at ~0 m/s. Every reading after the jump is a clock
    fault or measures the true 1 m/s; the fault holds learn_s, then the speed is right."""
    stream = Stream()
    jump_at, n = 300, 900
    after = []
    for i in range(n):
        real = i / HZ
        pos, vel = line(real)
        t = 3.0 + real + (1.0 if i >= jump_at else 0.0)
        speed = speed_of(stream.send(pose(t, pos, vel), 50.0 + real + 0.002))
        if i < jump_at:
            assert speed.fault is None
        else:
            after.append(speed)
    assert is_time_fault(after[0]) and "1.000 s ahead" in after[0].fault.reason
    learn = int(TrackerClockConfig().learn_s * HZ)
    assert all(is_time_fault(s) for s in after[:learn])
    for s in after:
        assert is_time_fault(s) or s.measured_mps is None or s.measured_mps > 0.95
        assert s.speed_mps >= 0.95  # measured, reported or the unknown speed: never ~0
    assert after[-1].fault is None and after[-1].measured_mps == pytest.approx(1.0, abs=0.01)


def test_a_step_back_of_101_s_is_a_fault_and_the_history_stays_bounded():
    """The finding: after a 101 s step back the history held 4,872 samples instead of ~125."""
    stream = Stream()
    step_at, n = 100, 5000
    limit = MotionLimits().history_s * HZ + 2
    faults, longest = [], 0
    for i in range(n):
        real = i / HZ
        pos, vel = line(real, 0.05)
        t = 200.0 + real - (101.0 if i >= step_at else 0.0)
        reading = stream.send(pose(t, pos, vel), 50.0 + real + 0.002)
        longest = max(longest, len(reading.history))
        if i >= step_at and i % 10 == 0:
            faults.append(is_time_fault(speed_of(reading)))
    assert faults[0], "the step back itself is a fault"
    assert longest <= limit, f"history of {longest} samples"
    assert len(stream.sub.latest().history) <= limit
    assert stream.sub.stats()["clock_faults"] >= 1
    assert not faults[-1]  # learned again on the new time base: no STOP for ever


@pytest.mark.parametrize("clock", ["honest", "twenty_times_slow", "each_sample_a_second"])
def test_a_one_hertz_circle_with_a_zero_velocity_field_is_never_zero(clock):
    """0.2 m radius at 1 Hz (1.26 m/s), velocity field 0. With honest times the speed is
    measured (and the lying velocity field is a fault); with a tracker clock that makes the
    50 ms window span whole turns the clock is a fault."""
    stream = Stream()
    checked = 0
    for i in range(int(2.0 * HZ)):
        real = i / HZ
        pos, _ = circle(real)
        t = {"honest": 3.0 + real, "twenty_times_slow": 3.0 + real / 20,
             "each_sample_a_second": 3.0 + i}[clock]
        speed = speed_of(stream.send(pose(t, pos), 50.0 + real + 0.002))
        assert speed.fault is not None or speed.speed_mps > 0.9 * CIRCLE_MPS, \
            f"{speed} at sample {i}"
        if clock == "honest" and speed.measured_mps is not None:
            checked += 1
            assert speed.measured_mps == pytest.approx(CIRCLE_MPS, abs=0.02)
            assert speed.fault is not None and "m/s" in speed.fault.reason
        elif clock != "honest" and i > 0.2 * HZ:
            checked += 1
            assert is_time_fault(speed)
    assert checked > HZ


def test_a_circle_whose_period_is_the_speed_window_is_measured():
    """Honest time, a 20 Hz circle of 25 mm (3.1 m/s) with velocity 0: the 50 ms window spans
    one whole turn and read 0 m/s with no fault. The longer windows see the motion (no window
    of 50 ms or more can see more than a half-turn chord: 50 mm in 75 ms, 0.67 m/s) and that
    against the velocity field of 0 is a fault."""
    stream = Stream()
    for i in range(int(0.6 * HZ)):
        real = i / HZ
        pos, _ = circle(real, radius=0.025, hz=20.0)
        speed = speed_of(stream.send(pose(3.0 + real, pos), 50.0 + real + 0.002))
    assert stream.sub.stats()["accepted"] == int(0.6 * HZ)  # every single-sample check passes
    assert speed.measured_mps > 0.5
    assert speed.fault is not None and speed.fault.name == "pose_implausible"
    assert "positions moved" in speed.fault.reason


def test_small_jumps_in_a_row_add_up_to_a_fault():
    """A clock running twice as fast once learned: 2.5 ms too much per sample, each step far
    below max_jump_s; the offset estimate follows at max_drift only, so it is a fault."""
    stream = Stream()
    t, first = 3.0, None
    for i in range(int(1.0 * HZ)):
        real = i / HZ
        t += (1.0 if i < 0.6 * HZ else 2.0) / HZ
        pos, vel = line(real, 0.1)
        speed = speed_of(stream.send(pose(t, pos, vel), 50.0 + real + 0.002))
        if first is None and speed.fault is not None:
            first = (i, speed.fault.reason)
    assert first is not None and "ahead of" in first[1]
    assert first[0] < 0.6 * HZ + 0.11 * HZ  # 0.1 s of max_jump_s at 1 s per s, plus drift
    assert is_time_fault(speed)  # and it stays: the clock never agrees again


# ------------------------------------------------------------------------- no false STOP


def test_a_real_stream_with_jitter_and_drift_raises_no_fault():
    """60 s at 400 Hz: the tracker's clock 500 ppm fast, delivery 1 ms + a few ms of jitter,
    and every 5 s a 40 ms hiccup that delivers a burst late. No clock fault, no STOP."""
    rng = random.Random(20)
    stream = Stream()
    hiccup_until = -1.0
    n = int(60 * HZ)
    for i in range(n):
        real = i / HZ
        pos, vel = circle(real, radius=0.3, hz=0.5)
        vel = tuple(v + rng.gauss(0.0, 0.02) for v in vel)
        pos = tuple(p + rng.gauss(0.0, 0.0005) for p in pos)
        if i % int(5 * HZ) == int(2 * HZ):
            hiccup_until = real + 0.04
        delay = 0.001 + min(rng.expovariate(1 / 0.002), 0.015)
        received = max(50.0 + real + delay, 50.0 + hiccup_until if real < hiccup_until else 0.0)
        reading = stream.send(pose(3.0 + real * 1.0005, pos, vel), received)
        assert reading.clock_fault is None, f"{reading.clock_fault} at {real:.3f} s"
        if i % 50 == 0 and i > 0:
            speed = speed_of(reading)
            assert speed.fault is None, speed.fault
            assert speed.measured_mps == pytest.approx(0.3 * math.pi, abs=0.1)
    assert stream.sub.stats() == {"accepted": n, "rejected": {}, "resyncs": 0,
                                  "clock_faults": 0}


def test_a_clock_drifting_past_the_bound_is_a_fault():
    """1 % slow (10 ms per second, ten times max_drift): the offset runs away within seconds."""
    clock = TrackerClock(TrackerClockConfig())
    verdicts = [clock.check(3.0 + (i / HZ) * 0.99, 50.0 + i / HZ) for i in range(int(20 * HZ))]
    first = next(i for i, f in enumerate(verdicts) if f is not None)
    assert 0.5 * HZ < first < 15 * HZ and "behind" in verdicts[first].reason


# ---------------------------------------------------------------------------- real Zenoh


def _put_paced(session, key: str, samples_at) -> None:
    start = time.monotonic()
    for i in range(120):
        real = time.monotonic() - start
        pos, vel = line(real)
        session.put(key, pose_to_json(samples_at(real, pos, vel), seq=i + 1, recv_mono=0.0,
                                      recv_wall=0.0))
        time.sleep(1 / HZ)


def _settle(sub, n: int) -> None:
    deadline = time.monotonic() + 5.0
    while sub.stats()["accepted"] + sum(sub.stats()["rejected"].values()) < n \
            and time.monotonic() < deadline:
        time.sleep(0.01)


@pytest.mark.parametrize("units", ["s", "ms"])
def test_over_zenoh_milliseconds_are_a_fault_and_seconds_are_not(units):
    port = free_port()
    keys = BusKeys.of("workcell/tt/")
    scale = 1000.0 if units == "ms" else 1.0
    with open_session(BusConfig(cell="tt", listen=(f"tcp/127.0.0.1:{port}",))) as session, \
            PoseSubscriber(session, keys.pose) as sub:
        _put_paced(session, keys.pose, lambda real, pos, vel: pose(
            scale * (7.0 + real), pos, tuple(v / scale for v in vel)))
        _settle(sub, 120)
        speed = speed_of(sub.latest())
    if units == "ms":
        assert is_time_fault(speed)
    else:  # a loaded machine may hold one delivery back: only a tracker-time fault counts
        assert sub.stats()["clock_faults"] == 0
        assert speed.fault is None and speed.measured_mps == pytest.approx(1.0, abs=0.05)


# ---------------------------------------------------------------------------------- config


def test_tracker_clock_settings_are_in_the_config_schema():
    config = parse_config({"tracker_clock": {"max_jump_s": 0.05, "max_drift": 0.0005}})
    assert config.tracker_clock == TrackerClockConfig(max_jump_s=0.05, max_drift=0.0005)
    with pytest.raises(ConfigError) as err:
        parse_config({"tracker_clock": {"max_jump_s": 5.0}}, "monitor.toml")
    assert str(err.value).startswith("monitor.toml: [tracker_clock] max_jump_s:")
    assert "\n" not in str(err.value)
    with pytest.raises(ConfigError, match=r"tracker_clock\.max_drift"):
        TrackerClockConfig(max_drift=0.0)
    with pytest.raises(ConfigError, match="unknown key 'jump'"):
        parse_config({"tracker_clock": {"jump": 1.0}})


def test_a_single_bad_timestamp_holds_the_fault_for_learn_s_only():
    stream = Stream(TrackerClockConfig(learn_s=0.25))
    faults = []
    for i in range(400):
        real = i / HZ
        pos, vel = line(real, 0.1)
        t = 3.0 + real + (30.0 if i == 100 else 0.0)
        faults.append(stream.send(pose(t, pos, vel), 50.0 + real + 0.002).clock_fault)
    assert faults[99] is None and faults[100] is not None
    cleared = next(i for i in range(101, 400) if faults[i] is None)
    assert cleared - 100 == pytest.approx(0.25 * HZ, abs=3)
    assert all(f is None for f in faults[cleared:])

