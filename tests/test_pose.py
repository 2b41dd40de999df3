"""OTUS codec, plausibility checks, pose samples on Zenoh and the UDP-to-Zenoh bridge."""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import socket
import struct
import subprocess
import sys
import time

import pytest
import zenoh

from monitor.bus.session import BusConfig, BusKeys, open_session
from monitor.pose.otus import (
    OTUS_SIZE,
    REJECT_REASONS,
    OtusSample,
    PacketError,
    decode_otus,
    encode_otus,
)
from monitor.pose.stream import (
    PoseLimits,
    PoseSubscriber,
    PoseValidator,
    pose_from_json,
    pose_to_json,
)
from tests.helpers import free_port


def sample(t: float = 1.0, x: float = 0.5, **kw) -> OtusSample:
    """A tool at rest (or moving at vx) at x metres, tracker time t seconds."""
    base = dict(device_id=3.0, timestamp=t, position_m=(x, 0.2, 1.1), velocity_m_s=(0.0, 0.0, 0.0),
                acceleration_m_s2=(0.0, 0.0, 0.0), quaternion_xyzw=(0.0, 0.0, 0.0, 1.0),
                angular_velocity_rad_s=(0.0, 0.0, 0.0),
                angular_acceleration_rad_s2=(0.0, 0.0, 0.0), button1=0.0, button2=1.0)
    base.update(kw)
    return OtusSample(**base)


def moving(n: int, dt: float = 0.0025, v: float = 1.0, t0: float = 1.0) -> list[OtusSample]:
    """n samples at 400 Hz moving along x at v m/s."""
    return [sample(t0 + i * dt, 0.5 + v * i * dt, velocity_m_s=(v, 0.0, 0.0)) for i in range(n)]


# --- codec ---------------------------------------------------------------------------------


def test_codec_round_trips_all_23_fields_in_vendor_order():
    s = OtusSample(1.0, 2.5, (0.1, 0.2, 0.3), (1.1, 1.2, 1.3), (2.1, 2.2, 2.3),
                   (0.0, 0.6, 0.0, 0.8), (3.1, 3.2, 3.3), (4.1, 4.2, 4.3), 1.0, 0.0)
    packet = encode_otus(s)
    assert len(packet) == OTUS_SIZE == 184
    assert decode_otus(packet) == s
    # byte offsets of the seeds' table: timestamp at 8, quaternion x at 88, button 2 at 176
    assert struct.unpack_from("<d", packet, 8)[0] == 2.5
    assert struct.unpack_from("<4d", packet, 88) == (0.0, 0.6, 0.0, 0.8)
    assert struct.unpack_from("<d", packet, 176)[0] == 0.0
    assert struct.unpack_from("<d", packet, 168)[0] == 1.0


@pytest.mark.parametrize("size", [0, 183, 185, 368])
def test_decode_rejects_wrong_size(size):
    with pytest.raises(PacketError) as err:
        decode_otus(bytes(size))
    assert err.value.reason == "size"


# --- plausibility ----------------------------------------------------------------------------


def _bad(field: str, value) -> OtusSample:
    return dataclasses.replace(sample(1.0025), **{field: value})


@pytest.mark.parametrize(("bad", "reason"), [
    pytest.param(_bad("position_m", (math.nan, 0.2, 1.1)), "non_finite", id="nan_position"),
    pytest.param(_bad("timestamp", math.inf), "non_finite", id="inf_timestamp"),
    pytest.param(_bad("quaternion_xyzw", (0.0, 0.0, 0.0, 1.1)), "quaternion_norm",
                 id="quaternion_too_long"),
    pytest.param(_bad("quaternion_xyzw", (0.0, 0.0, 0.0, 0.0)), "quaternion_norm",
                 id="quaternion_zero"),
    pytest.param(sample(0.9), "timestamp_backwards", id="timestamp_backwards"),
    pytest.param(sample(1.0), "timestamp_repeat", id="timestamp_repeats"),
    pytest.param(sample(1.0025, x=0.6), "speed", id="position_jump_100mm_in_2.5ms"),
    pytest.param(_bad("velocity_m_s", (9.0, 0.0, 0.0)), "speed", id="reported_speed"),
    pytest.param(_bad("acceleration_m_s2", (0.0, 500.0, 0.0)), "acceleration",
                 id="reported_acceleration"),
    pytest.param(_bad("angular_velocity_rad_s", (0.0, 0.0, 50.0)), "angular_speed",
                 id="reported_angular_speed"),
    pytest.param(_bad("quaternion_xyzw", (0.0, 0.0, math.sin(0.5), math.cos(0.5))),
                 "angular_speed", id="orientation_jump_57deg_in_2.5ms"),
])
def test_validator_rejects_each_kind_of_bad_sample(bad, reason):
    v = PoseValidator(PoseLimits())
    assert v.check(sample(1.0)) is None
    rejection = v.check(bad)
    assert rejection is not None and rejection.reason == reason
    assert reason in REJECT_REASONS
    assert v.rejected[reason] == 1
    assert v.previous == sample(1.0)  # the last good sample stays in use


def test_velocity_jump_is_an_acceleration_rejection():
    v = PoseValidator()
    assert v.check(sample(1.0, velocity_m_s=(0.0, 0.0, 0.0))) is None
    bad = v.check(sample(1.0025, velocity_m_s=(2.0, 0.0, 0.0)))  # 800 m/s² implied
    assert bad is not None and bad.reason == "acceleration"


def test_out_of_bounds_when_a_volume_is_configured():
    v = PoseValidator(PoseLimits(bounds_min_m=(-2.5, -2.5, 0.0), bounds_max_m=(2.5, 2.5, 3.0)))
    assert v.check(sample(1.0)) is None
    assert v.check(sample(1.1, x=7.0)).reason == "out_of_bounds"


def test_realistic_motion_with_tracker_noise_is_accepted():
    """1 m/s at 400 Hz with ±10 mm position noise and 30 mm/s velocity noise: no rejections."""
    import random

    rng = random.Random(4)
    v = PoseValidator()
    for s in moving(400):
        noisy = dataclasses.replace(
            s, position_m=tuple(p + rng.uniform(-0.01, 0.01) for p in s.position_m),
            velocity_m_s=tuple(p + rng.uniform(-0.03, 0.03) for p in s.velocity_m_s))
        assert v.check(noisy) is None
    assert v.accepted == 400


def test_single_outlier_rejected_then_stream_continues():
    v = PoseValidator()
    good = moving(10)
    for s in good[:5]:
        assert v.check(s) is None
    outlier = dataclasses.replace(good[5], position_m=(3.0, 3.0, 3.0))
    assert v.check(outlier).reason == "speed"
    for s in good[6:]:
        assert v.check(s) is None


def test_plausible_jump_after_a_gap_is_accepted():
    v = PoseValidator()
    for s in moving(5):
        assert v.check(s) is None
    assert v.check(sample(2.0, x=2.0)) is None  # 1.5 m in ~1 s: a person can do that


def test_impossible_jump_is_adopted_only_after_resync_samples_in_a_row():
    v = PoseValidator(PoseLimits(resync_samples=5))
    for s in moving(5):
        assert v.check(s) is None
    far = [sample(1.02 + i * 0.0025, x=3.0) for i in range(7)]  # 2.5 m in 10 ms
    verdicts = [v.check(s) for s in far]
    assert [r is None for r in verdicts] == [False] * 4 + [True] * 3
    assert v.resyncs == 1 and v.rejected["speed"] == 4


def test_pose_json_round_trip_and_malformed():
    s = moving(2)[1]
    payload = pose_to_json(s, seq=7, recv_mono=12.0, recv_wall=1.7e9, bridge="b1")
    back, body = pose_from_json(payload)
    assert back == s and body["seq"] == 7 and body["schema"] == "workcell.tracker.pose/1"
    for bad in (b"{", b'{"schema": "other"}', json.dumps({**body, "position_m": [1, 2]}).encode()):
        with pytest.raises(PacketError) as err:
            pose_from_json(bad)
        assert err.value.reason == "malformed"


# --- Zenoh and UDP -----------------------------------------------------------------------------



def test_pose_subscriber_keeps_latest_accepted_sample_and_its_age():
    port = free_port()
    keys = BusKeys.of("workcell/t1/")
    rejects = []
    with open_session(BusConfig(cell="t1", listen=(f"tcp/127.0.0.1:{port}",))) as session, \
            PoseSubscriber(session, keys.pose, on_reject=rejects.append) as sub:
        assert sub.latest() is None and sub.pose_time() is None
        good = moving(3)
        for i, s in enumerate(good):
            session.put(keys.pose, pose_to_json(s, seq=i + 1, recv_mono=0.0, recv_wall=0.0))
        session.put(keys.pose, b"not json")
        session.put(keys.pose, pose_to_json(good[0], seq=9, recv_mono=0.0, recv_wall=0.0))
        deadline = time.monotonic() + 3.0
        while len(rejects) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        reading = sub.latest()
        assert reading is not None and reading.sample == good[2]
        assert 0.0 <= reading.age < 3.0
        assert [r.reason for r in sub.drain_rejections()] == ["malformed", "timestamp_backwards"]
        assert sub.stats()["accepted"] == 3
        tool = reading.tool_pose()
        assert tool.position_m == good[2].position_m and tool.time == reading.received


def wait_alert(alerts: list, kind: str, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if any(json.loads(a.payload.to_bytes())["kind"] == kind for a in list(alerts)):
            return True
        time.sleep(0.01)
    return False


def test_udp_to_zenoh_bridge_with_real_sockets():
    """`monitor bridge otus` as a subprocess: real UDP on loopback in, Zenoh pose samples out."""
    zport, uport = free_port(), free_port(socket.SOCK_DGRAM)
    keys = BusKeys.of("workcell/bridgetest/")
    got: list[zenoh.Sample] = []
    bad: list[zenoh.Sample] = []
    alerts: list[zenoh.Sample] = []
    cfg = BusConfig(cell="bridgetest", listen=(f"tcp/127.0.0.1:{zport}",))
    with open_session(cfg) as session:
        session.declare_subscriber(keys.pose, got.append)
        session.declare_subscriber(keys.pose + "/rejected", bad.append)
        session.declare_subscriber(keys.alert, alerts.append)
        proc = subprocess.Popen(
            [sys.executable, "-m", "monitor", "bridge", "otus",
             "--listen", f"127.0.0.1:{uport}", "--cell", "bridgetest", "--mode", "peer",
             "--connect", f"tcp/127.0.0.1:{zport}"],
            stderr=subprocess.PIPE, text=True)
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
                deadline = time.monotonic() + 15.0
                k = 0
                while not got and time.monotonic() < deadline:  # until the bridge is up
                    # tracker time stays below the stream's 1.0 s however long start-up takes
                    udp.sendto(encode_otus(sample(0.9 - 0.4 * 0.99 ** k)), ("127.0.0.1", uport))
                    k += 1
                    time.sleep(0.05)
                assert got, "bridge did not publish"
                stream = moving(50)  # tracker time from 1.0 s on
                for i, s in enumerate(stream):
                    udp.sendto(encode_otus(s), ("127.0.0.1", uport))
                    if i == 20:
                        udp.sendto(b"\x00" * 100, ("127.0.0.1", uport))  # wrong size
                        udp.sendto(encode_otus(dataclasses.replace(
                            s, quaternion_xyzw=(0.0, 0.0, 0.0, 2.0))), ("127.0.0.1", uport))
                    time.sleep(0.001)
                deadline = time.monotonic() + 30.0
                while time.monotonic() < deadline and not any(
                        pose_from_json(g.payload.to_bytes())[0] == stream[-1] for g in got[-3:]):
                    time.sleep(0.01)
                # the stream stops: one pose_silence alert after pose_timeout (0.1 s)
                assert wait_alert(alerts, "pose_silence", timeout=30.0)
        finally:
            proc.terminate()
            _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    samples = [pose_from_json(s.payload.to_bytes()) for s in got]
    # in order and unchanged; poses go out with DROP congestion control (the newest pose
    # matters, a late one is worthless), so on a loaded machine some of a burst sent 1 ms
    # apart are dropped (44 of 50 arrived beside 2 busy processes and a mutation run)
    received = [s for s, _ in samples if s.timestamp >= 1.0]
    where = [stream.index(s) for s in received]  # ValueError: a pose that was never sent
    assert where == sorted(set(where)) and len(received) >= 0.5 * len(stream), \
        f"{len(received)} of {len(stream)} poses, at {where}"
    seqs = [b["seq"] for _, b in samples]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    reasons = [json.loads(s.payload.to_bytes())["reason"] for s in bad]
    assert reasons == ["size", "quaternion_norm"]
    kinds = [json.loads(a.payload.to_bytes())["kind"] for a in alerts]
    assert kinds.count("pose_rejected") == 1  # rate-limited: the second rejection is held back
    assert kinds[-1] == "pose_silence"
    assert "rejected {'size': 1, 'quaternion_norm': 1}" in err


def test_safety_bus_pose_subscriber_feeds_pose_time():
    from monitor.bus.session import SafetyBus

    port = free_port()
    cfg = BusConfig(cell="ps", instance="m", listen=(f"tcp/127.0.0.1:{port}",))
    with SafetyBus(cfg) as bus, bus.pose_subscriber() as sub, \
            open_session(BusConfig(cell="ps", connect=(f"tcp/127.0.0.1:{port}",))) as bridge:
        deadline = time.monotonic() + 3.0
        while sub.pose_time() is None and time.monotonic() < deadline:
            bridge.put(bus.keys.pose, pose_to_json(sample(time.monotonic()), seq=1,
                                                   recv_mono=0.0, recv_wall=0.0))
            time.sleep(0.02)
        assert sub.pose_time() is not None
        assert abs(sub.pose_time() - time.monotonic()) < 3.0  # receive time, monitor's clock


# --- bounded pose JSON ----------------------------------------------------------------------


def _valid_body() -> dict:
    return json.loads(pose_to_json(moving(2)[1], seq=1, recv_mono=1.0, recv_wall=1.7e9))


@pytest.mark.parametrize("mutate, expected", [
    pytest.param(lambda t: t.replace('"seq": 1', '"seq": ' + "9" * 400), "400 characters",
                 id="400-digit-int"),
    pytest.param(lambda t: t.replace('"seq": 1', '"seq": 1e400'), "out of range",
                 id="overflowing-float"),
    pytest.param(lambda t: t.replace('"seq": 1', '"seq": NaN'), "NaN is not a number",
                 id="nan-token"),
    pytest.param(lambda t: t.replace('"seq": 1', '"seq": 1e13'), "out of range",
                 id="huge-magnitude"),
    pytest.param(lambda t: t.replace('"seq": 1', '"pad": "' + "x" * 5000 + '", "seq": 1'),
                 "bytes", id="long-payload"),
    pytest.param(lambda t: t.replace('"seq": 1', '"seq": ' + "[" * 2000 + "]" * 2000),
                 "", id="deep-nesting"),
    pytest.param(lambda t: "[1, 2]", "not a JSON object", id="not-an-object"),
])
def test_pose_json_values_are_bounded_with_a_one_line_rejection(mutate, expected):
    text = mutate(json.dumps(_valid_body()))
    with pytest.raises(PacketError) as err:
        pose_from_json(text.encode())
    assert err.value.reason == "malformed"
    assert expected in str(err.value) and "\n" not in str(err.value)
    assert err.value.__cause__ is None  # no chained traceback in the log


def test_pose_json_booleans_are_not_numbers():
    body = _valid_body()
    body["position_m"] = [True, 0.0, 1.0]
    with pytest.raises(PacketError, match="is not a number"):
        pose_from_json(json.dumps(body).encode())


def test_subscriber_measures_the_tool_speed_of_a_lying_stream():
    """Positions move at 1 m/s, the velocity field says 0: every check of a single sample
    passes, but the reading's measured speed is 1 m/s and the stream is pose_implausible."""
    port = free_port()
    keys = BusKeys.of("workcell/t2/")
    lying = [dataclasses.replace(s, velocity_m_s=(0.0, 0.0, 0.0)) for s in moving(40)]
    with open_session(BusConfig(cell="t2", listen=(f"tcp/127.0.0.1:{port}",))) as session, \
            PoseSubscriber(session, keys.pose) as sub:
        for i, s in enumerate(lying):
            session.put(keys.pose, pose_to_json(s, seq=i + 1, recv_mono=0.0, recv_wall=0.0))
        deadline = time.monotonic() + 3.0
        while sub.stats()["accepted"] < len(lying) and time.monotonic() < deadline:
            time.sleep(0.01)
        reading = sub.latest()
        assert reading is not None and reading.sample == lying[-1]
        speed = reading.tool_speed()
    assert speed.measured_mps == pytest.approx(1.0, rel=1e-6)
    assert speed.speed_mps == pytest.approx(1.0, rel=1e-6) and speed.reported_mps == 0.0
    assert speed.fault is not None and speed.fault.name == "pose_implausible"


def _bridge_stderr(argv: list[str], seconds: float) -> str:
    """`monitor bridge otus ARGV` for ``seconds``, then SIGINT; its stderr."""
    proc = subprocess.Popen([sys.executable, "-m", "monitor", "bridge", "otus",
                             "--listen", f"127.0.0.1:{free_port(socket.SOCK_DGRAM)}",
                             "--unmatched-warn", "0.5", *argv],
                            stderr=subprocess.PIPE, text=True)
    head = ""
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:  # the bridge is up when it names its UDP port
            line = proc.stderr.readline()
            head += line
            if "UDP" in line or not line:
                break
        time.sleep(seconds)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
    # read through the same file object: communicate(timeout=...) reads the pipe itself and
    # would miss the lines readline() already buffered
    err = head + proc.stderr.read()
    proc.stderr.close()
    assert proc.returncode in (0, 130), err
    return err


def test_bridge_without_an_endpoint_or_a_subscriber_warns():
    """No --connect/--zenoh-listen/--zenoh-config: the poses can reach nobody; said at start,
    and again when no subscriber matched the pose key for --unmatched-warn seconds."""
    err = _bridge_stderr(["--cell", "nobody"], 1.5)
    assert "warning: no --connect, --zenoh-listen or --zenoh-config" in err, err
    assert "warning: no subscriber to workcell/nobody/tracker/pose for 0.5 s" in err


def test_bridge_with_a_subscriber_does_not_warn():
    zport = free_port()
    keys = BusKeys.of("workcell/heard/")
    with open_session(BusConfig(cell="heard", listen=(f"tcp/127.0.0.1:{zport}",))) as session:
        session.declare_subscriber(keys.pose, lambda s: None)
        err = _bridge_stderr(["--cell", "heard", "--connect", f"tcp/127.0.0.1:{zport}"], 1.5)
    assert "warning" not in err, err


def test_the_documented_packet_layout_is_the_codecs():
    """docs/otus.md's table, row by row, against monitor.pose.stream: byte range, order and
    field."""
    import re
    from pathlib import Path

    from monitor.pose.otus import OTUS_FORMAT

    doc = (Path(__file__).resolve().parents[1] / "docs" / "otus.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| (\d+)-(\d+) \| ([^|]+) \| `([a-z_0-9]+)(?:\[(\d)\])?` \|", doc, re.M)
    assert len(rows) == 23, rows
    assert OTUS_FORMAT == "<23d" and "little-endian" in doc and "(float64)" in doc
    assert int(rows[-1][1]) + 1 == OTUS_SIZE == 184 and "184 bytes" in doc
    # a packet whose k-th double is k: each documented field must decode to its row's index
    decoded = decode_otus(struct.pack("<23d", *range(23)))
    for k, (first, last, name, attr, index) in enumerate(rows):
        assert (int(first), int(last)) == (8 * k, 8 * k + 7), name
        value = getattr(decoded, attr)
        assert (value[int(index)] if index else value) == k, f"row {k} ({name}): {attr}"
