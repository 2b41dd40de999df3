"""`monitor bridge ros2`: rmw_zenoh's format without ROS (monitor/adapters/ros2*.py,
docs/ros2.md). A raw Zenoh subscriber on 127.0.0.1 plays the ROS 2 node: it listens on the key
rmw_zenoh's subscriber would use (spelled out here, not built by the code under test), decodes
the payloads with rosbags, parses the attachment and reads the liveliness tokens."""

from __future__ import annotations

import dataclasses
import json
import threading
import time

import pytest
import zenoh

from monitor.adapters import ros2_wire as wire
from monitor.adapters.follower import Follower, subscribe
from monitor.adapters.ros2 import Ros2Output, Ros2Settings, speed_override
from monitor.adapters.snapshot import SafetySnapshot
from monitor.bus.session import BusConfig, BusKeys, SafetyBus, open_session
from monitor.errors import ConfigError
from monitor.policy import Command, Reason
from monitor.wire.consumer import COMMAND_SCHEMA, CommandWatchdog
from monitor.wire.inbox import Inbox
from monitor.wire.signing import load_private_key, load_public_key, new_key_pair
from tests.helpers import (
    assert_one_line,
    assert_one_line_error,
    free_port,
    run_monitor,
    wait_for,
)

rosbags_typesys = pytest.importorskip("rosbags.typesys")
TS = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)

CELL = "ad"
TTL_MS = 300
FLOAT64, STRING, DIAG = ("std_msgs/msg/Float64", "std_msgs/msg/String",
                         "diagnostic_msgs/msg/DiagnosticArray")
# what a ROS 2 subscriber of /workcell/ad/<topic> declares under rmw_zenoh (design doc format)
SPEED_KEY = ("0/workcell/ad/speed_override/std_msgs::msg::dds_::Float64_/"
             "RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a")
DIAG_KEY = ("0/workcell/ad/diagnostics/diagnostic_msgs::msg::dds_::DiagnosticArray_/"
            "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e")
JSON_KEY = ("0/workcell/ad/command_json/std_msgs::msg::dds_::String_/"
            "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")


# ---- the format, offline -------------------------------------------------------------------

@pytest.mark.parametrize("ros_type", [FLOAT64, STRING, DIAG])
def test_type_hashes_equal_rosbags_rihs01(ros_type):
    assert wire.TYPE_HASHES[ros_type] == TS.hash_rihs01(ros_type)


def test_the_string_hash_is_the_one_in_rmw_zenohs_design_doc():
    assert wire.TYPE_HASHES[STRING] == (
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")


def test_keys_and_tokens_match_the_design_docs_examples():
    # verbatim examples of rmw_zenoh's docs/design.md (Jazzy)
    assert wire.node_token(0, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "", "listener") == \
        "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    assert wire.publisher_token(0, "8b20917502ee955ac4476e0266340d5c", 0, 10, "", "talker",
                                "/chatter", STRING, 7) == (
        "@ros2_lv/0/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        "std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,")
    assert wire.data_key(0, "/chatter", STRING) == (
        "0/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")
    assert wire.data_key(0, "/workcell/ad/speed_override", FLOAT64) == SPEED_KEY
    assert wire.data_key(7, "/a/b", DIAG).startswith(
        "7/a/b/diagnostic_msgs::msg::dds_::DiagnosticArray_/RIHS01_")
    assert wire.mangle("/workcell/ad") == "%workcell%ad"
    # Humble: no type hashes, the placeholder in their place
    assert wire.data_key(0, "/chatter", STRING, "humble") == \
        "0/chatter/std_msgs::msg::dds_::String_/TypeHashNotSupported"
    assert "/std_msgs::msg::dds_::String_/TypeHashNotSupported/::,7:" in wire.publisher_token(
        0, "z", 0, 1, "", "talker", "/chatter", STRING, 7, "humble")


def test_attachment_layout_is_seq_timestamp_gid_length_gid():
    gid = bytes(range(16))
    raw = wire.attachment(5, 1_700_000_000_123_456_789, gid)
    assert len(raw) == 33
    assert raw[:8] == (5).to_bytes(8, "little")
    assert raw[8:16] == (1_700_000_000_123_456_789).to_bytes(8, "little")
    assert raw[16] == 16 and raw[17:] == gid
    assert wire.parse_attachment(raw) == wire.Attachment(5, 1_700_000_000_123_456_789, gid)
    for bad in (raw[:-1], raw[:16] + b"\x0f" + raw[17:], b""):
        with pytest.raises(ValueError):
            wire.parse_attachment(bad)
    with pytest.raises(ValueError):
        wire.attachment(1, 1, b"short")


@pytest.mark.parametrize("value", [0.0, 0.4, 1.0, -0.0])
def test_float64_is_byte_identical_to_rosbags(value):
    msg = TS.types[FLOAT64](data=value)
    assert wire.cdr_float64(value) == bytes(TS.serialize_cdr(msg, FLOAT64))
    assert wire.cdr_float64(value)[:4] == b"\x00\x01\x00\x00"  # CDR_LE encapsulation


@pytest.mark.parametrize("text", ["", "a", "abc", "abcd", "Zone ü ✓", '{"state": "STOP"}'])
def test_string_is_byte_identical_to_rosbags(text):
    assert wire.cdr_string(text) == bytes(TS.serialize_cdr(TS.types[STRING](data=text), STRING))


def _rosbags_diag(stamp_ns, frame, statuses):
    T = TS.types
    sec, ns = divmod(stamp_ns, 1_000_000_000)
    return T[DIAG](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=ns), frame_id=frame),
        status=[T["diagnostic_msgs/msg/DiagnosticStatus"](
            level=st.level, name=st.name, message=st.message, hardware_id=st.hardware_id,
            values=[T["diagnostic_msgs/msg/KeyValue"](key=k, value=v) for k, v in st.values])
            for st in statuses])


def test_diagnostic_array_is_byte_identical_to_rosbags_across_alignments():
    # strings of every length mod 4 and a level byte before each: every padding case
    statuses = tuple(wire.DiagnosticStatus(
        level=i % 4, name="n" * i, message="m" * (i + 1), hardware_id="h" * (i + 2),
        values=tuple((f"k{'x' * j}", "v" * (i + j)) for j in range(i % 3)))
        for i in range(6))
    for frame in ("", "f", "/workcell/ad"):
        ours = wire.cdr_diagnostic_array(1_700_000_001_000_000_007, frame, statuses)
        theirs = TS.serialize_cdr(_rosbags_diag(1_700_000_001_000_000_007, frame, statuses),
                                  DIAG)
        assert ours == bytes(theirs)
    assert wire.cdr_diagnostic_array(0, "", ()) == bytes(TS.serialize_cdr(
        _rosbags_diag(0, "", ()), DIAG))


# ---- live: monitor bus -> follower -> ROS 2 output -> raw Zenoh "ROS node" -----------------

class RosNode:
    """A raw Zenoh subscriber on rmw_zenoh's keys, decoding like a ROS node would."""

    def __init__(self, session: zenoh.Session) -> None:
        self.samples: dict[str, list[tuple[object, wire.Attachment, float]]] = {
            SPEED_KEY: [], DIAG_KEY: [], JSON_KEY: []}
        self.lock = threading.Lock()
        types = {SPEED_KEY: FLOAT64, DIAG_KEY: DIAG, JSON_KEY: STRING}

        def on(key):
            def cb(sample):
                msg = TS.deserialize_cdr(sample.payload.to_bytes(), types[key])
                att = wire.parse_attachment(sample.attachment.to_bytes())
                with self.lock:
                    self.samples[key].append((msg, att, time.monotonic()))
            return cb

        self.subs = [session.declare_subscriber(k, on(k)) for k in types]

    def speeds(self) -> list[float]:
        with self.lock:
            return [m.data for m, _, _ in self.samples[SPEED_KEY]]

    def messages(self, key) -> list:
        with self.lock:
            return [m for m, _, _ in self.samples[key]]

    def last(self, key):
        with self.lock:
            return self.samples[key][-1][0] if self.samples[key] else None


@pytest.fixture()
def cell(tmp_path):
    private, public, _ = new_key_pair(tmp_path / "monitor.key")
    port = free_port()
    cfg = BusConfig(cell=CELL, instance="mon-ad", listen=(f"tcp/127.0.0.1:{port}",),
                    heartbeat_hz=20.0, ttl_ms=TTL_MS, signing_key=str(private))
    keys = BusKeys.of(f"workcell/{CELL}/")
    dog = CommandWatchdog(public_keys=(load_public_key(public),), cell=CELL,
                          key_expr=keys.command)
    inbox = Inbox(64)
    connect = (f"tcp/127.0.0.1:{port}",)
    with SafetyBus(cfg) as bus, \
            open_session(BusConfig(cell=CELL, instance="adapter", connect=connect)) as session, \
            open_session(BusConfig(cell=CELL, instance="rosnode", connect=connect)) as ros:
        entities = subscribe(session, keys, inbox)
        node = RosNode(ros)
        out = Ros2Output(session, Ros2Settings(0, "/workcell/ad", "workcell_monitor_bridge",
                                               0.1))
        follower = Follower(dog, inbox, cameras=("cam0",))
        stop = threading.Event()
        runner = threading.Thread(target=follower.run, args=([out], stop, 0.02))
        runner.start()
        try:
            yield bus, session, ros, keys, node, out
        finally:
            stop.set()
            runner.join(5)
            out.close()
            for e in (*entities, *node.subs):
                e.undeclare()


def test_a_raw_zenoh_subscriber_decodes_the_verdict_with_rosbags(cell):
    bus, _, _, _, node, _ = cell
    bus.publish_command(Command("SLOW", 0.4, (Reason("warning_zone", "person 1 in W",
                                                     zone_id="W"),)))
    assert wait_for(lambda: 0.4 in node.speeds())
    diag = wait_for(lambda: (d := node.last(DIAG_KEY)) and d.status[0].message.startswith(
        "SLOW") and d)
    assert diag and diag.status[0].level == wire.DIAG_WARN
    values = {kv.key: kv.value for kv in diag.status[0].values}
    assert values["reason_code"] == "warning_zone" and values["zone_id"] == "W"
    assert values["instance"] == "mon-ad" and values["speed_scale"] == "0.4"
    assert [s.name for s in diag.status] == ["workcell_monitor_bridge: command",
                                            "workcell_monitor_bridge: camera cam0"]
    assert abs(diag.header.stamp.sec - time.time()) < 5 and diag.header.frame_id == \
        "/workcell/ad"
    body = json.loads(wait_for(lambda: (m := node.last(JSON_KEY)) and
                               '"SLOW"' in m.data and m.data))
    assert body["state"] == "SLOW" and body["zone_id"] == "W"

    with node.lock:
        atts = [a for _, a, _ in node.samples[SPEED_KEY]]
        diag_gids = {a.gid for _, a, _ in node.samples[DIAG_KEY]}
    seqs = [a.seq for a in atts]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # +1 per sample, none lost
    assert len({a.gid for a in atts}) == 1 and diag_gids and not diag_gids & {atts[0].gid}
    assert all(abs(a.timestamp_ns / 1e9 - time.time()) < 5 for a in atts)


def test_liveliness_tokens_show_the_node_and_its_publishers(cell):
    _, session, ros, _, _, out = cell
    zid = str(session.zid())
    prefix = f"@ros2_lv/0/{zid}/0/"

    def tokens() -> list[str]:  # a loaded machine may answer before the tokens reached ros
        keys = sorted(str(r.ok.key_expr) for r in ros.liveliness().get("@ros2_lv/0/**",
                                                                        timeout=3.0) if r.ok)
        return len([k for k in keys if k.startswith(prefix)]) >= 4 and keys

    keys = wait_for(tokens, what="the node's and its three publishers' liveliness tokens")
    assert f"{prefix}0/NN/%/%workcell%ad/workcell_monitor_bridge" in keys
    assert (f"{prefix}1/MP/%/%workcell%ad/workcell_monitor_bridge/%workcell%ad%speed_override/"
            f"{SPEED_KEY.split('/', 4)[4]}/::,1:,:,:,,") in keys
    assert len([k for k in keys if k.startswith(prefix) and "/MP/" in k]) == 3
    out.close()  # the tokens go with the output
    assert wait_for(lambda: not [r for r in ros.liveliness().get(f"{prefix}**", timeout=0.5)
                                 if r.ok])


def test_silence_is_a_zero_override_and_the_adapter_leaves_with_zero(cell):
    bus, _, _, _, node, out = cell
    bus.publish_command(Command("RUN", 1.0))
    assert wait_for(lambda: node.speeds() and node.speeds()[-1] == 1.0)
    bus.close()  # the monitor goes: its final STOP, then silence
    assert wait_for(lambda: node.speeds()[-1] == 0.0)
    time.sleep(TTL_MS / 1000 + 0.2)
    assert node.speeds()[-1] == 0.0
    out.close()  # the follower still ticks beside it: its heartbeat may come after the close's
    assert wait_for(lambda: any("adapter stopped" in m.status[0].message  # STOP (2 threads)
                                for m in node.messages(DIAG_KEY)), what="adapter stopped")
    assert node.speeds()[-1] == 0.0


def test_a_forged_run_never_gives_a_non_zero_override(cell, tmp_path):
    bus, session, _, keys, node, _ = cell
    bus.publish_command(Command("STOP", 0.0, (Reason("protective_zone", "person 1 in P",
                                                     zone_id="P"),)))
    assert wait_for(lambda: (d := node.last(DIAG_KEY)) and "person 1 in P" in
                    d.status[0].message)
    forger = load_private_key(new_key_pair(tmp_path / "forger.key")[0])
    body = {"schema": COMMAND_SCHEMA, "cell": CELL, "instance": "mon-ad", "boot": "forged",
            "seq": 10**6, "state": "RUN", "speed_scale": 1.0, "ttl_ms": 1000}
    payload = json.dumps(body).encode()
    for attachment in (None, forger.sign(keys.command, payload)):
        for _ in range(20):
            session.put(keys.command, payload, attachment=attachment)
            time.sleep(0.01)
    time.sleep(0.3)
    assert node.speeds() and set(node.speeds()) == {0.0}
    # a forged ROS-side sample is not ours to stop, but ours never say RUN either
    assert all(json.loads(m.data)["state"] == "STOP" for m, _, _ in node.samples[JSON_KEY])


# ---- the publication policy: on change at once, else the heartbeat -------------------------

def _snap(mono: float, state: str = "RUN", scale: float = 1.0, counter: int = 0):
    return SafetySnapshot(state=state, speed_scale=scale, latched=False, reset_possible=False,
                          reason_code="", reason="", zone_id=None, seq=counter, age_ms=5.0,
                          counter=counter, mono=mono, wall=1.7e9 + mono)


def test_publishes_on_change_at_once_and_otherwise_on_the_heartbeat():
    with open_session(BusConfig(cell=CELL, instance="alone",
                                listen=(f"tcp/127.0.0.1:{free_port()}",))) as session:
        out = Ros2Output(session, Ros2Settings(3, "/t", "n", 0.1))
        try:
            # 1 s of unchanged ticks at 50 Hz: the first tick, then one every 100 ms
            for i in range(50):
                out.publish(_snap(i * 0.02, counter=i))
            assert out.published == 10  # ticks 0, 5, 10 ... 45
            before = out.published
            out.publish(_snap(0.995, "STOP", 0.0, counter=51))  # a change: at once
            assert out.published == before + 1
            out.publish(_snap(1.0, "STOP", 0.0, counter=52))  # same content, 5 ms later
            assert out.published == before + 1
            assert out.topics["speed_override"].seq == out.published
            assert out.topics["speed_override"].key.startswith("3/t/speed_override/")
        finally:
            out.close()


@pytest.mark.parametrize("state,scale", [("STOP", 1.0), ("BOGUS", 1.0), ("SLOW", 1.5),
                                         ("RUN", float("nan")), ("RUN", -1.0)])
def test_the_override_is_zero_for_anything_but_a_valid_run_or_slow(state, scale):
    assert speed_override(dataclasses.replace(_snap(0.0), state=state,
                                              speed_scale=scale)) == 0.0


def _settings(**over):
    import argparse
    args = dict(cell="ad", ros_namespace=None, ros_domain_id=0, ros_node="n",
                ros_heartbeat_ms=100.0)
    return Ros2Settings.of(argparse.Namespace(**{**args, **over}))


@pytest.mark.parametrize("over,needle", [
    ({"ros_namespace": "workcell/x"}, "--ros-namespace"),
    ({"ros_namespace": "/9x"}, "--ros-namespace"),
    ({"ros_namespace": "/a//b"}, "--ros-namespace"),
    ({"ros_node": "a/b"}, "--ros-node"),
    ({"ros_domain_id": 300}, "--ros-domain-id"),
    ({"ros_domain_id": -1}, "--ros-domain-id"),
    ({"ros_heartbeat_ms": 5.0}, "--ros-heartbeat-ms"),
    ({"ros_heartbeat_ms": float("nan")}, "--ros-heartbeat-ms"),
    ({"ros_distro": "iron"}, "--ros-distro"),
])
def test_bad_ros_options_are_one_line_errors(over, needle):
    with pytest.raises(ConfigError) as exc:
        _settings(**over)
    assert_one_line(exc.value, needle)


def test_a_bad_ros_option_stops_the_command_with_one_line():
    proc = run_monitor("bridge", "ros2", "--unauthenticated", "--connect",
                       f"tcp/127.0.0.1:{free_port()}", "--ros-namespace", "no slash",
                       "--duration", "1", timeout=60)
    assert_one_line_error(proc, "--ros-namespace")


def test_default_namespace_makes_any_cell_id_a_ros_name():
    cfg = _settings(cell="7-north")
    assert cfg.namespace == "/workcell/_7_north" and wire.is_ros_name(cfg.namespace, True)
    assert cfg.distro == "jazzy" and _settings(ros_distro="humble").distro == "humble"


def test_the_bridge_command_publishes_for_a_ros_node_and_leaves_with_zero(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    private, public, _ = new_key_pair(tmp_path / "monitor.key")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = BusConfig(cell=CELL, instance="mon-ad", listen=(endpoint,), heartbeat_hz=20.0,
                    ttl_ms=1000, signing_key=str(private))
    root = Path(__file__).resolve().parent.parent
    with SafetyBus(cfg) as bus, open_session(BusConfig(
            cell=CELL, instance="rosnode", connect=(endpoint,))) as ros:
        node = RosNode(ros)
        proc = subprocess.Popen(
            [sys.executable, "-m", "monitor", "bridge", "ros2", "--cell", CELL, "--connect",
             endpoint, "--monitor-key", str(public), "--duration", "60"],
            env=dict(os.environ, PYTHONPATH=str(root)), stderr=subprocess.PIPE, text=True)
        try:
            def slow_seen() -> bool:  # the pipeline hands in its command every poll, as live
                bus.publish_command(Command("SLOW", 0.5))
                return 0.5 in node.speeds()

            assert wait_for(slow_seen, what=lambda: (proc.poll(), node.speeds()[-5:]))
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
        assert proc.returncode == 0, err
        assert "ros2" in err and "Traceback" not in err
        assert wait_for(lambda: node.speeds()[-1] == 0.0)  # its last word is STOP
        for s in node.subs:
            s.undeclare()
