"""`monitor bridge ros2`: the verdict as ROS 2 topics over Zenoh, in rmw_zenoh's format, without
a ROS installation (docs/ros2.md).

Three topics under a namespace (default ``/workcell/<cell>``), each a Zenoh publisher on the key
a ROS 2 node running rmw_zenoh subscribes to, with the attachment rmw_zenoh requires, and a
liveliness token per publisher (plus one for the node) so ``ros2 topic list`` shows them:

- ``speed_override`` (``std_msgs/msg/Float64``): the verdict's speed scale, 0.0 on STOP, on
  silence, on a bad signature, on a stale command and when the adapter stops; never the raw
  command's;
- ``diagnostics`` (``diagnostic_msgs/msg/DiagnosticArray``): the state, its reasons and faults,
  the heartbeat counter, one status per camera;
- ``command_json`` (``std_msgs/msg/String``): the snapshot as JSON, for humans.

All three are published together when what they show changes (checked every tick of the
adapter) and otherwise every ``--ros-heartbeat-ms`` (100 ms by default): a subscriber's deadman
timer can then tell a live adapter from a dead one.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import time

import zenoh

from monitor.adapters import ros2_wire as wire
from monitor.adapters.snapshot import SafetySnapshot
from monitor.errors import ConfigError

DEFAULT_NODE = "workcell_monitor_bridge"
DEFAULT_HEARTBEAT_MS = 100.0
TOPICS = {  # relative name -> ROS type
    "speed_override": "std_msgs/msg/Float64",
    "diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "command_json": "std_msgs/msg/String",
}
DEPTH = 1  # KEEP_LAST(1): only the newest verdict matters
LEVEL = {"RUN": wire.DIAG_OK, "SLOW": wire.DIAG_WARN, "STOP": wire.DIAG_ERROR}


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("ROS 2 (rmw_zenoh format)")
    g.add_argument("--ros-domain-id", type=int, default=0, metavar="N",
                   help="ROS_DOMAIN_ID of the ROS 2 side, 0-232 (default 0)")
    g.add_argument("--ros-namespace", default=None, metavar="NS",
                   help="namespace of the topics (default /workcell/<cell>)")
    g.add_argument("--ros-node", default=DEFAULT_NODE, metavar="NAME",
                   help=f"node name shown by `ros2 node list` (default {DEFAULT_NODE})")
    g.add_argument("--ros-distro", choices=wire.DISTROS, default="jazzy",
                   help="key format: jazzy (RIHS01 type hashes; also Kilted, Rolling) or humble "
                   "(no type hashes) (default jazzy)")
    g.add_argument("--ros-heartbeat-ms", type=float, default=DEFAULT_HEARTBEAT_MS,
                   metavar="MS", help="publish at least this often when nothing changes, "
                   f"10-1000 (default {DEFAULT_HEARTBEAT_MS:g})")


@dataclasses.dataclass(frozen=True)
class Ros2Settings:
    domain: int
    namespace: str
    node: str
    heartbeat_s: float
    distro: str = "jazzy"

    @classmethod
    def of(cls, args: argparse.Namespace) -> Ros2Settings:
        domain = args.ros_domain_id
        if not 0 <= domain <= 232:
            raise ConfigError(f"--ros-domain-id {domain}: must be 0-232")
        ns = args.ros_namespace or f"/workcell/{wire.ros_segment(args.cell)}"
        if not wire.is_ros_name(ns, absolute=True):
            raise ConfigError(f"--ros-namespace {ns!r}: not a ROS 2 namespace (/a/b, segments "
                              "of letters, digits and _, not starting with a digit)")
        if not wire.is_ros_name(args.ros_node, absolute=False) or "/" in args.ros_node:
            raise ConfigError(f"--ros-node {args.ros_node!r}: not a ROS 2 node name")
        if not 10.0 <= args.ros_heartbeat_ms <= 1000.0:
            raise ConfigError(f"--ros-heartbeat-ms {args.ros_heartbeat_ms:g}: must be 10-1000")
        distro = getattr(args, "ros_distro", "jazzy")
        if distro not in wire.DISTROS:
            raise ConfigError(f"--ros-distro {distro!r}: one of {', '.join(wire.DISTROS)}")
        return cls(domain, ns, args.ros_node, args.ros_heartbeat_ms / 1000.0, distro)


def make_outputs(args: argparse.Namespace, session: zenoh.Session, keys) -> list:
    return [Ros2Output(session, Ros2Settings.of(args))]


def speed_override(s: SafetySnapshot) -> float:
    """The verdict's scale; 0.0 for anything but a RUN or SLOW verdict in [0, 1]."""
    ok = s.state in ("RUN", "SLOW") and 0.0 <= s.speed_scale <= 1.0
    return float(s.speed_scale) if ok else 0.0


def _text(v: object) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.1f}"
    return str(v)


def diagnostic_statuses(s: SafetySnapshot, node: str) -> tuple[wire.DiagnosticStatus, ...]:
    """The state with its reasons and faults, then one status per camera."""
    message = s.state + (f": {s.reason}" if s.reason else "")
    values = (
        ("state", s.state), ("speed_scale", f"{speed_override(s):g}"),
        ("reason_code", s.reason_code), ("reason", s.reason), ("zone_id", _text(s.zone_id)),
        ("faults", ",".join(s.faults)), ("latched", _text(s.latched)),
        ("reset_possible", _text(s.reset_possible)), ("seq", _text(s.seq)),
        ("age_ms", _text(s.age_ms)), ("counter", str(s.counter)), ("cell", s.cell),
        ("instance", s.instance), ("zone_hash", s.zone_hash))
    main = wire.DiagnosticStatus(LEVEL.get(s.state, wire.DIAG_ERROR), f"{node}: command",
                                 message, s.instance, values)
    cams = tuple(wire.DiagnosticStatus(
        wire.DIAG_OK if ok else wire.DIAG_ERROR, f"{node}: camera {cid}",
        "ok" if ok else "fault, or unknown while the command is overridden", cid)
        for cid, ok in sorted(s.cameras.items()))
    return (main, *cams)


def command_json(s: SafetySnapshot) -> str:
    body = dataclasses.asdict(s)
    body.pop("mono")
    body["speed_scale"] = speed_override(s)
    body["faults"] = list(s.faults)
    return json.dumps(body, sort_keys=True)


def _shown(s: SafetySnapshot) -> tuple:
    """What the topics show, without what moves every tick (counter, age, clocks, seq)."""
    return (s.state, speed_override(s), s.latched, s.reset_possible, s.reason_code, s.reason,
            s.zone_id, s.faults, tuple(sorted(s.cameras.items())), s.instance, s.zone_hash)


class _Topic:
    """One ROS 2 publisher: its Zenoh publisher, liveliness token, GID and sequence."""

    def __init__(self, session: zenoh.Session, cfg: Ros2Settings, zid: str, entity_id: int,
                 name: str, ros_type: str, realtime: bool) -> None:
        self.topic = f"{cfg.namespace}/{name}"
        self.ros_type = ros_type
        self.key = wire.data_key(cfg.domain, self.topic, ros_type, cfg.distro)
        self.token_key = wire.publisher_token(cfg.domain, zid, 0, entity_id, cfg.namespace,
                                              cfg.node, self.topic, ros_type, DEPTH,
                                              cfg.distro)
        self.gid = wire.gid_of(self.token_key)
        self.seq = 0
        # DROP: a congested link never blocks the adapter's tick; the heartbeat resends
        self.publisher = session.declare_publisher(
            self.key, congestion_control=zenoh.CongestionControl.DROP, express=realtime,
            priority=zenoh.Priority.REAL_TIME if realtime else zenoh.Priority.DATA)
        self.token = session.liveliness().declare_token(self.token_key)

    def put(self, payload: bytes) -> None:
        self.seq += 1
        self.publisher.put(payload, attachment=wire.attachment(self.seq, time.time_ns(),
                                                               self.gid))

    def close(self) -> None:
        for entity in (self.token, self.publisher):
            with contextlib.suppress(Exception):  # the session may be closing already
                entity.undeclare()


class Ros2Output:
    """The ROS 2 output: three topics, published on change and on the heartbeat."""

    name = "ros2"

    def __init__(self, session: zenoh.Session, cfg: Ros2Settings) -> None:
        self.cfg = cfg
        zid = str(session.zid())
        self.node_key = wire.node_token(cfg.domain, zid, 0, cfg.namespace, cfg.node)
        self.node_token = session.liveliness().declare_token(self.node_key)
        self.topics: dict[str, _Topic] = {}
        try:
            for i, (name, ros_type) in enumerate(TOPICS.items(), start=1):
                self.topics[name] = _Topic(session, cfg, zid, i, name, ros_type,
                                           realtime=name == "speed_override")
        except Exception:
            self.close()
            raise
        self.last: SafetySnapshot | None = None
        self._shown: tuple | None = None
        self._sent_at = float("-inf")
        self.published = 0  # samples per topic, heartbeats included

    def publish(self, snapshot: SafetySnapshot) -> None:
        self.last = snapshot
        shown = _shown(snapshot)
        due = snapshot.mono - self._sent_at >= self.cfg.heartbeat_s - 1e-6  # float grid
        if shown == self._shown and not due:
            return
        self._send(snapshot)
        self._shown, self._sent_at = shown, snapshot.mono

    def _send(self, s: SafetySnapshot) -> None:
        # the speed override first: it is what a robot acts on
        self.topics["speed_override"].put(wire.cdr_float64(speed_override(s)))
        self.topics["diagnostics"].put(wire.cdr_diagnostic_array(
            int(s.wall * 1e9), self.cfg.namespace, diagnostic_statuses(s, self.cfg.node)))
        self.topics["command_json"].put(wire.cdr_string(command_json(s)))
        self.published += 1

    def close(self) -> None:
        """A last STOP (0.0) on every topic, then the tokens go: the ROS side sees the adapter
        leave instead of its last RUN."""
        if self.last is not None and len(self.topics) == len(TOPICS):
            with contextlib.suppress(Exception):  # best effort: the deadman covers the rest
                self._send(dataclasses.replace(
                    self.last, state="STOP", speed_scale=0.0, reason_code="adapter_stopped",
                    reason="the adapter stopped", zone_id=None, wall=time.time(),
                    cameras={c: False for c in self.last.cameras}))
        for topic in self.topics.values():
            topic.close()
        with contextlib.suppress(Exception):
            self.node_token.undeclare()
