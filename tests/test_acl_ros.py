"""The shipped ROS-side router config (deploy/zenoh/router-ros.json5) refuses a forged
``speed_override`` from every user but the bridge's: a real Zenoh router started from it on
127.0.0.1 with TLS and users, the ROS 2 output (`monitor bridge ros2`) as user "ros-bridge", a
raw Zenoh subscriber on rmw_zenoh's key as the robot's node, and a forger that copies the
bridge's GID and takes a higher sequence number (docs/ros2.md, "What a ROS node can trust")."""

from __future__ import annotations

import struct
import threading
import time
from pathlib import Path

import pytest
import zenoh

from monitor.adapters import ros2_wire as wire
from monitor.adapters.ros2 import Ros2Output, Ros2Settings
from monitor.adapters.snapshot import SafetySnapshot
from monitor.bus.session import BusConfig, open_session
from tests.helpers import free_port, put_until, wait_for
from tests.tls import secure_router

DEPLOY = Path(__file__).resolve().parents[1] / "deploy" / "zenoh"
USERS = {"monitor": "m-pw", "ros-bridge": "b-pw", "robot-driver": "d-pw", "ros-tools": "t-pw",
         "stranger": "s-pw"}  # "stranger": in the users file, in no subject of the ACL
FLOAT64 = "std_msgs/msg/Float64"
# what rmw_zenoh's subscriber of /workcell/cell1/speed_override declares (design doc format)
SPEED_KEY = ("0/workcell/cell1/speed_override/std_msgs::msg::dds_::Float64_/"
             "RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a")
# a topic the site lists for its nodes (router-ros.json5, ros_nodes_write)
OWN_KEY = wire.data_key(0, "/joint_states", FLOAT64)
# puts with wildcards: a deny on /workcell/ alone would let these through to the bridge's
# subscribers (they intersect its key without naming workcell)
WILDCARD_KEYS = ("0/**", "**", "0/*/cell1/speed_override/*/*", "*/workcell/**")


def _snapshot(mono: float) -> SafetySnapshot:
    return SafetySnapshot(state="STOP", speed_scale=0.0, latched=True, reset_possible=False,
                          reason_code="no_command", reason="no command", zone_id=None,
                          seq=None, age_ms=None, counter=int(mono * 10), mono=mono,
                          wall=time.time(), cell="cell1")


class Samples:
    """Every sample one subscriber got: (key, value, attachment or None)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.got: list[tuple[str, float, wire.Attachment | None]] = []
        self.lock = threading.Lock()

        def on(sample) -> None:
            raw = sample.payload.to_bytes()
            value = wire_value(raw)
            att = sample.attachment
            with self.lock:
                self.got.append((str(sample.key_expr), value,
                                 wire.parse_attachment(att.to_bytes()) if att else None))
        self.sub = session.declare_subscriber(key, on)

    def values(self) -> list[float]:
        with self.lock:
            return [v for _, v, _ in self.got]

    def last(self):
        with self.lock:
            return self.got[-1] if self.got else None


def wire_value(raw: bytes) -> float:
    """A Float64's value from its CDR (header, then 8 bytes); NaN for anything else."""
    return struct.unpack("<d", raw[4:12])[0] if len(raw) == 12 else float("nan")


@pytest.fixture(scope="module")
def ros(tmp_path_factory):
    """A router from the shipped ROS config and one TLS client session per user."""
    tmp = tmp_path_factory.mktemp("acl-ros")
    port = free_port()
    conf, tls = secure_router(tmp, DEPLOY / "router-ros.json5", USERS, port)

    def client(user: str) -> BusConfig:
        return BusConfig(cell="cell1", mode="client", instance=user.replace("-", ""),
                         zenoh_config_file=str(DEPLOY / "client-secure.json5"),
                         connect=(f"tls/localhost:{port}",), tls_root_ca=str(tls["ca"]),
                         user=user, password=USERS[user])

    with zenoh.open(conf) as router:
        sessions = {u: open_session(client(u)) for u in USERS}
        bridge = Ros2Output(sessions["ros-bridge"],
                            Ros2Settings(0, "/workcell/cell1", "workcell_monitor_bridge", 0.1))
        try:
            yield {"router": router, "sessions": sessions, "bridge": bridge,
                   "client": client}
        finally:
            bridge.close()
            for s in sessions.values():
                s.close()


def _bridge_says_zero(ros, seen: Samples) -> wire.Attachment:
    """The bridge publishes 0.0 until the robot's node has one: its newest attachment."""
    def arrived():
        ros["bridge"].publish(_snapshot(time.monotonic()))
        last = seen.last()
        return last is not None and last[2] is not None and last[1] == 0.0 and last[2]
    return wait_for(arrived, timeout=30, what="the bridge's 0.0 at the robot's node")


def _forge(session: zenoh.Session, gid: bytes, seq: int, n: int = 30,
           keys: tuple[str, ...] = (SPEED_KEY, *WILDCARD_KEYS)) -> None:
    for i in range(n):
        att = wire.attachment(seq + 1000 + i, time.time_ns(), gid)
        for key in keys:
            session.put(key, wire.cdr_float64(1.0), attachment=att)


def test_a_forged_speed_override_is_refused_for_every_user_but_the_bridges(ros):
    s = ros["sessions"]
    seen = Samples(s["robot-driver"], SPEED_KEY)
    own = Samples(s["robot-driver"], OWN_KEY)
    try:
        att = _bridge_says_zero(ros, seen)
        # a ROS node's user and a user in no subject: 30 forged 1.0 each, with the bridge's
        # GID and a higher seq, on the topic's key and on wildcard keys that intersect it
        for user in ("ros-tools", "stranger"):
            _forge(s[user], att.gid, att.seq)
        # the forger is connected and may publish its own topic: the refusal is the ACL's
        put_until(lambda: s["ros-tools"].put(OWN_KEY, wire.cdr_float64(0.5)),
                  lambda: 0.5 in own.values(), what="the ROS node's own topic at the robot's node")
        # the bridge's next samples arrive after the forged ones had their turn
        before = len(seen.values())
        wait_for(lambda: _bridge_says_zero(ros, seen) and len(seen.values()) >= before + 3,
                 timeout=30, what="three more of the bridge's samples")
        time.sleep(0.3)  # the forged ones had longer than the bridge's to arrive
        values = seen.values()
        assert values and set(values) == {0.0}, \
            f"{values.count(1.0)} forged 1.0 samples reached the robot's node"
        with seen.lock:
            gids = {a.gid for _, _, a in seen.got if a is not None}
        assert gids == {att.gid}
    finally:
        seen.sub.undeclare()
        own.sub.undeclare()


def test_the_same_forgery_from_the_bridges_user_arrives(ros):
    """The control: the forger's samples are deliverable; the user decides, not the format."""
    second = open_session(ros["client"]("ros-bridge"))
    seen = Samples(ros["sessions"]["robot-driver"], SPEED_KEY)
    try:
        att = _bridge_says_zero(ros, seen)
        _forge(second, att.gid, att.seq, n=3, keys=(SPEED_KEY,))
        assert wait_for(lambda: seen.values().count(1.0) >= 3,
                        timeout=20, what="the bridge user's own 1.0 samples")
    finally:
        seen.sub.undeclare()
        second.close()


def test_no_node_but_the_bridge_shows_up_as_a_publisher_of_its_topics(ros):
    s = ros["sessions"]
    topic = wire.mangle("/workcell/cell1/speed_override")
    forged = f"@ros2_lv/0/{s['ros-tools'].zid()}/0/9/MP/%/%/forger/{topic}/x/y/::,1:,:,:,,"
    subscriber = f"@ros2_lv/0/{s['ros-tools'].zid()}/0/8/MS/%/%/forger/{topic}/x/y/::,1:,:,:,,"
    own = f"@ros2_lv/0/{s['ros-tools'].zid()}/0/7/MP/%/%/forger/%joint_states/x/y/::,1:,:,:,,"
    tokens = [s["ros-tools"].liveliness().declare_token(k) for k in (forged, subscriber, own)]
    try:
        def graph() -> set[str]:
            return {str(r.ok.key_expr) for r in s["robot-driver"].liveliness().get(
                "@ros2_lv/0/**", timeout=2.0) if r.ok is not None}
        assert wait_for(lambda: {subscriber, own} <= graph(), timeout=20,
                        what="the node's own tokens in the graph")
        bridge_pub = [k for k in graph() if "/MP/" in k and topic in k]
        assert forged not in graph() and bridge_pub, graph()
        assert all(str(s["ros-bridge"].zid()) in k for k in bridge_pub)
    finally:
        for t in tokens:
            t.undeclare()


def test_no_wildcard_token_stands_for_a_publisher_of_the_bridges_topics(ros):
    """Issue 48: Zenoh matches an ACL rule when it includes the message's key, so publisher
    tokens with wildcards passed the deny rule (it includes none of them) under the allow of
    "@ros2_lv/**", and a query for the publishers of a /workcell/ topic found them. Now a ROS
    node holds publisher tokens only of the topics it may publish; its node, subscriber and own
    publisher tokens still show."""
    s = ros["sessions"]
    z = s["ros-tools"].zid()
    topic = wire.mangle("/workcell/cell1/speed_override")
    wild = [f"@ros2_lv/0/{z}/0/9/MP/%/%/forger/*/x/y/::,1:,:,:,,",
            f"@ros2_lv/0/{z}/0/9/MP/%/%/forger/**", f"@ros2_lv/0/{z}/0/9/MP/**",
            f"@ros2_lv/0/{z}/0/9/*/%/%/forger/{topic}/x/y/::,1:,:,:,,",
            f"@ros2_lv/0/{z}/0/9/MP/%/%/forger/$*workcell$*/x/y/::,1:,:,:,,",
            f"@ros2_lv/0/{z}/0/9/MP/%/%/forger/%$*/x/y/::,1:,:,:,,", "@ros2_lv/**",
            "0/workcell/**/@adv/**"]
    node = wire.node_token(0, str(z), 0, "/", "forger")
    own = [node, f"@ros2_lv/0/{z}/0/7/MP/%/%/forger/%joint_states/x/y/::,1:,:,:,,",
           f"@ros2_lv/0/{z}/0/8/MS/%/%/forger/{topic}/x/y/::,1:,:,:,,",
           f"@ros2_lv/0/{z}/0/6/MP/%/%/forger/%robot%arm%state/x/y/::,1:,:,:,,"]
    tokens = [s["ros-tools"].liveliness().declare_token(k) for k in wild + own]
    try:
        def graph() -> set[str]:
            return {str(r.ok.key_expr) for r in s["robot-driver"].liveliness().get(
                "@ros2_lv/0/**", timeout=2.0) if r.ok is not None}
        assert wait_for(lambda: set(own) <= graph(), timeout=20,
                        what="the node's own tokens in the graph")
        publishers = {str(r.ok.key_expr) for r in s["robot-driver"].liveliness().get(
            f"@ros2_lv/0/*/*/*/MP/*/*/*/{topic}/**", timeout=2.0) if r.ok is not None}
        assert not set(wild) & graph(), set(wild) & graph()
        assert publishers and all(str(s["ros-bridge"].zid()) in k for k in publishers), \
            publishers
        adv = {str(r.ok.key_expr) for r in s["robot-driver"].liveliness().get(
            "0/workcell/**/@adv/**", timeout=2.0) if r.ok is not None}
        assert "0/workcell/**/@adv/**" not in adv
    finally:
        for t in tokens:
            t.undeclare()


def test_a_user_in_no_subject_can_do_nothing(ros):
    s = ros["sessions"]
    own = Samples(s["robot-driver"], OWN_KEY)
    stranger = Samples(s["stranger"], OWN_KEY)
    try:
        def put_round() -> None:
            s["stranger"].put(OWN_KEY, wire.cdr_float64(0.25))
            s["ros-tools"].put(OWN_KEY, wire.cdr_float64(0.75))
        put_until(put_round, lambda: 0.75 in own.values(), what="ros-tools' sample")
        put_round()
        time.sleep(0.3)
        assert 0.25 not in own.values()  # its put is refused
        # and nothing reaches its subscriber (its own put reaches it inside its session)
        assert 0.75 not in stranger.values()
    finally:
        own.sub.undeclare()
        stranger.sub.undeclare()


def test_only_the_monitors_user_puts_on_the_monitors_keys(ros):
    """The bridge follows the monitor's signed commands on the same router: the monitor's user
    may put them, a ROS node's may not (a signature would refuse it too; the router first)."""
    s = ros["sessions"]
    key = "workcell/cell1/safety/command"
    got: list[str] = []
    sub = s["ros-bridge"].declare_subscriber(key, lambda x: got.append(
        x.payload.to_bytes().decode()))
    try:
        def put_round() -> None:  # the refused first, each round
            for user in ("ros-tools", "stranger", "robot-driver", "monitor"):
                s[user].put(key, user)
        put_until(put_round, lambda: "monitor" in got, what="the monitor's put")
        put_round()
        time.sleep(0.3)  # the refused ones had longer than the monitor's to arrive
        assert set(got) == {"monitor"}, f"puts the ACL let through: {got}"
    finally:
        sub.undeclare()
