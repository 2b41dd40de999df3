"""Zenoh bus of the monitor: commands, heartbeat, alerts, detections, status, resets, liveliness.

Keys (``prefix`` defaults to ``workcell/<cell>/``):

=================================  =========================================================
``<prefix>safety/command``          RUN/SLOW/STOP; on every change and as a heartbeat at
                                    ``heartbeat_hz``. Priority REAL_TIME, express, BLOCK
                                    with a bounded wait (``block_wait_ms``).
``<prefix>safety/alert``            alerts (JSON; JPEG snapshot as the sample attachment)
``<prefix>safety/detections``       persons and zone hits per processed frame (dashboards)
``<prefix>safety/status``           queryable: state, config hash, fps, uptime, last reset
``<prefix>safety/reset``            subscribed: ``{"operator": "...", "request_id": "..."}``
``<prefix>safety/alive/<instance>`` liveliness token of the running monitor
``<prefix>tracker/pose``            tool pose samples (``monitor.pose``)
=================================  =========================================================

Every payload is a UTF-8 JSON object with the envelope ``schema`` (e.g.
``workcell.safety.command/1``), ``seq`` (per key, +1 per message, from 1 in each session),
``mono`` (sender's monotonic clock, s), ``wall`` (sender's Unix time, s), ``ttl_ms``,
``config_hash``, ``instance`` and ``boot`` (the Zenoh session id: a new one after a restart).

A subscriber that stops reading (hung controller, full TCP buffers) costs a command put at most
``block_wait_ms`` (Zenoh's ``wait_before_close``); then Zenoh gives up on that link instead of
stalling the monitor for its default 5 s. Puts that reach no subscriber and failed puts are counted
and reported by the status queryable (``puts_unmatched``, ``put_errors``).

Consumer rule (``CommandWatchdog``, shown by ``monitor watch``): the controller treats the cell
as STOP unless it holds a command that arrived less than ``ttl_ms`` ago, whose ``seq`` is
larger than the previous one of the same ``boot``, and whose monitor's liveliness token is
present. The heartbeat never repeats RUN for a stalled pipeline: if the service stops handing
in commands for ``stall_timeout``, the heartbeat sends STOP (reason ``stalled``).
"""

from __future__ import annotations

import collections
import contextlib
import json
import math
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import zenoh

from monitor.alerts import AlertLimiter, AlertLimits, alert_to_dict
from monitor.errors import ConfigError
from monitor.policy import STOP, Command, Reason, ResetRequest
from monitor.types import Alert, Persons, ZoneReport

SCHEMA_VERSION = 1
COMMAND_SCHEMA = f"workcell.safety.command/{SCHEMA_VERSION}"
ALERT_SCHEMA = f"workcell.safety.alert/{SCHEMA_VERSION}"
DETECTIONS_SCHEMA = f"workcell.safety.detections/{SCHEMA_VERSION}"
STATUS_SCHEMA = f"workcell.safety.status/{SCHEMA_VERSION}"
RESET_SCHEMA = f"workcell.safety.reset/{SCHEMA_VERSION}"
MODES = ("peer", "client", "router")


@dataclass(frozen=True)
class BusConfig:
    """Where and how the monitor talks Zenoh. Times in ms unless the name says otherwise.

    ``zenoh_config_file`` (JSON5) is the base; the fields set here override it (None = keep the
    file's value). Without a file: mode peer, multicast scouting off.
    """

    cell: str = "cell1"
    prefix: str | None = None  # default f"workcell/{cell}/"
    instance: str = field(default_factory=lambda: f"monitor-{socket.gethostname()}")
    mode: str | None = None  # "peer" | "client" | "router"; None = file's value or peer
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    zenoh_config_file: str | None = None
    tls_root_ca: str | None = None  # CA that signed the other side's certificate
    tls_cert: str | None = None  # this side's certificate (listen side, and client for mTLS)
    tls_key: str | None = None
    tls_mutual: bool | None = None
    user: str | None = None
    password: str | None = None
    heartbeat_hz: float = 10.0
    ttl_ms: int = 300  # consumers treat a command older than this as STOP
    stall_timeout: float = 0.5  # s without publish_command -> heartbeat sends STOP "stalled"
    block_wait_ms: int = 50  # bounded wait of BLOCK congestion control before the link closes
    lease_ms: int | None = 2000  # link lease: a hung peer's liveliness token vanishes after it
    config_hash: str = ""

    def __post_init__(self) -> None:
        if self.mode is not None and self.mode not in MODES:
            raise ConfigError(f"bus.mode: {self.mode!r} is not one of {', '.join(MODES)}")
        if not self.cell or any(c in self.cell for c in "/*$?#"):
            raise ConfigError(f"bus.cell: {self.cell!r} must be a non-empty key chunk")
        if not self.instance or any(c in self.instance for c in "/*$?#"):
            raise ConfigError(f"bus.instance: {self.instance!r} must be a non-empty key chunk")
        if not (math.isfinite(self.heartbeat_hz) and 0.1 <= self.heartbeat_hz <= 1000):
            raise ConfigError(f"bus.heartbeat_hz: {self.heartbeat_hz!r} not within 0.1..1000")
        if self.ttl_ms <= 1000.0 / self.heartbeat_hz:
            raise ConfigError(f"bus.ttl_ms: {self.ttl_ms} must exceed the heartbeat period "
                              f"{1000.0 / self.heartbeat_hz:.0f} ms")
        if (self.user is None) != (self.password is None):
            raise ConfigError("bus.user/password: give both or neither")
        if (self.tls_cert is None) != (self.tls_key is None):
            raise ConfigError("bus.tls_cert/tls_key: give both or neither")
        if self.block_wait_ms <= 0 or self.stall_timeout <= 0:
            raise ConfigError("bus.block_wait_ms/stall_timeout: must be positive")

    @property
    def key_prefix(self) -> str:
        prefix = self.prefix if self.prefix is not None else f"workcell/{self.cell}/"
        return prefix if prefix.endswith("/") else prefix + "/"


@dataclass(frozen=True)
class BusKeys:
    """The key expressions under one prefix."""

    command: str
    alert: str
    detections: str
    status: str
    reset: str
    alive: str  # prefix of the liveliness tokens: alive + "/" + instance
    pose: str

    @classmethod
    def of(cls, prefix: str) -> BusKeys:
        p = prefix if prefix.endswith("/") else prefix + "/"
        return cls(command=p + "safety/command", alert=p + "safety/alert",
                   detections=p + "safety/detections", status=p + "safety/status",
                   reset=p + "safety/reset", alive=p + "safety/alive", pose=p + "tracker/pose")


def zenoh_config(bus: BusConfig) -> zenoh.Config:
    """Build the Zenoh session config from the service's bus config."""
    try:
        conf = (zenoh.Config.from_file(bus.zenoh_config_file) if bus.zenoh_config_file
                else zenoh.Config())
    except Exception as exc:
        raise ConfigError(f"{bus.zenoh_config_file}: not a valid Zenoh config: {exc}") from None

    def put(key: str, value) -> None:
        try:
            conf.insert_json5(key, json.dumps(value))
        except Exception as exc:
            raise ConfigError(f"bus: Zenoh rejects {key}={value!r}: {exc}") from None

    if bus.mode is not None or bus.zenoh_config_file is None:
        put("mode", bus.mode or "peer")
    if bus.listen:
        put("listen/endpoints", list(bus.listen))
    if bus.connect:
        put("connect/endpoints", list(bus.connect))
    put("scouting/multicast/enabled", bus.multicast_scouting)
    put("transport/link/tx/queue/congestion_control/block/wait_before_close",
        int(bus.block_wait_ms * 1000))  # microseconds
    if bus.lease_ms is not None:
        put("transport/link/tx/lease", int(bus.lease_ms))
    if bus.tls_root_ca:
        put("transport/link/tls/root_ca_certificate", bus.tls_root_ca)
    if bus.tls_cert and bus.tls_key:
        put("transport/link/tls/listen_certificate", bus.tls_cert)
        put("transport/link/tls/listen_private_key", bus.tls_key)
        put("transport/link/tls/connect_certificate", bus.tls_cert)
        put("transport/link/tls/connect_private_key", bus.tls_key)
    if bus.tls_mutual is not None:
        put("transport/link/tls/enable_mtls", bus.tls_mutual)
    if bus.user is not None:
        put("transport/auth/usrpwd/user", bus.user)
        put("transport/auth/usrpwd/password", bus.password)
    return conf


def open_session(bus: BusConfig) -> zenoh.Session:
    """Open a Zenoh session; a failure (bad endpoint, port taken) is a ConfigError."""
    conf = zenoh_config(bus)
    try:
        return zenoh.open(conf)
    except Exception as exc:
        raise ConfigError(f"bus: cannot open the Zenoh session ({bus.mode or 'peer'}, "
                          f"listen={list(bus.listen)}, connect={list(bus.connect)}): {exc}"
                          ) from None


def parse_reset(payload: bytes, received: float) -> ResetRequest:
    """Parse a ``safety/reset`` payload; ``received`` = arrival time (s, monotonic).
    Raises ValueError with the fault."""
    body = json.loads(payload)
    if not isinstance(body, dict):
        raise ValueError("reset payload is not a JSON object")
    operator = body.get("operator")
    if not isinstance(operator, str) or not operator.strip():
        raise ValueError("reset request without an operator id")
    return ResetRequest(operator=operator.strip(), time=received,
                        request_id=str(body.get("request_id", "")),
                        note=str(body.get("note", "")))


def reset_payload(operator: str, request_id: str = "", note: str = "") -> bytes:
    return json.dumps({"schema": RESET_SCHEMA, "operator": operator, "request_id": request_id,
                       "note": note, "wall": time.time()}).encode()


def detections_body(persons: Persons | None, zone_report: ZoneReport | None) -> dict:
    body: dict = {}
    if persons is not None:
        if persons.frame is not None:
            f = persons.frame
            body["frame"] = {"camera_id": f.camera_id, "seq": f.seq,
                             "capture_time": f.capture_time, "width": f.width,
                             "height": f.height}
        body["boxes_px"] = [[round(float(v), 1) for v in b] for b in persons.boxes_px]
        body["scores"] = [round(float(s), 3) for s in persons.scores]
    if zone_report is not None:
        body["hits"] = [dict(h.__dict__) for h in zone_report.hits]
        body["masked"] = list(zone_report.masked)
        body["tool_separation_m"] = zone_report.tool_separation_m
        body["required_separation_m"] = zone_report.required_separation_m
    return body


class SafetyBus:
    """The monitor's side of the bus. Use as a context manager: the session is closed on exit
    and a last STOP (reason ``shutdown``) goes out first.

    Thread-safe: the pipeline calls ``publish_command`` per step; the heartbeat thread
    re-publishes the latest command at ``heartbeat_hz``.
    """

    def __init__(self, config: BusConfig, *, alert_limits: AlertLimits | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.keys = BusKeys.of(config.key_prefix)
        self._clock = clock
        self._limiter = AlertLimiter(alert_limits or AlertLimits())
        self._lock = threading.Lock()  # seq counters, latest command, counters
        self._cmd_lock = threading.Lock()  # serialises command puts: seq order == wire order
        self._seq: dict[str, int] = collections.defaultdict(int)
        self._counters: dict[str, collections.Counter] = {
            "puts": collections.Counter(), "unmatched": collections.Counter(),
            "errors": collections.Counter()}
        self._latest: Command | None = None
        self._latest_time: float | None = None
        self._published: Command | None = None
        self._resets: collections.deque[ResetRequest] = collections.deque(maxlen=16)
        self._resets_invalid = 0
        self._last_reset: dict | None = None
        self._status_extra: dict = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._session: zenoh.Session | None = None
        self._boot = ""
        self._started_mono = clock()
        self._started_wall = time.time()
        self._heartbeats = 0

    # --- lifecycle ---------------------------------------------------------------------------

    def __enter__(self) -> SafetyBus:
        self._session = open_session(self.config)
        try:
            s = self._session
            self._boot = str(s.zid())
            self._pub_command = s.declare_publisher(
                self.keys.command, encoding="application/json",
                priority=zenoh.Priority.REAL_TIME, express=True,
                congestion_control=zenoh.CongestionControl.BLOCK)
            self._pub_alert = s.declare_publisher(
                self.keys.alert, encoding="application/json",
                priority=zenoh.Priority.DATA_HIGH, congestion_control=zenoh.CongestionControl.DROP)
            self._pub_detections = s.declare_publisher(
                self.keys.detections, encoding="application/json",
                priority=zenoh.Priority.DATA, congestion_control=zenoh.CongestionControl.DROP)
            self._queryable = s.declare_queryable(self.keys.status, self._on_status_query)
            self._reset_sub = s.declare_subscriber(self.keys.reset, self._on_reset)
            self._token = s.liveliness().declare_token(f"{self.keys.alive}/{self.config.instance}")
            self._thread = threading.Thread(target=self._heartbeat_loop, name="bus-heartbeat",
                                            daemon=True)
            self._thread.start()
        except BaseException:
            self._session.close()
            self._session = None
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the heartbeat, send STOP (shutdown), close the session. Idempotent."""
        if self._session is None:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        try:
            self._put_command(Command(STOP, 0.0, (Reason("shutdown", "monitor shutting down"),),
                                      since=self._clock()), heartbeat=False)
            self._token.undeclare()
        finally:
            self._session.close()
            self._session = None

    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("SafetyBus is not open (use it as a context manager)")
        return self._session

    @property
    def boot(self) -> str:
        return self._boot

    def pose_subscriber(self, limits=None, on_reject=None):
        """A ``monitor.pose.PoseSubscriber`` on ``<prefix>tracker/pose`` of this session
        (use it as a context manager inside the bus's ``with``)."""
        from monitor.pose import PoseSubscriber

        return PoseSubscriber(self.session, self.keys.pose, limits, self._clock, on_reject)

    # --- publishing --------------------------------------------------------------------------

    def _envelope(self, key: str, schema: str, body: dict) -> dict:
        self._seq[key] += 1
        return {"schema": schema, "seq": self._seq[key], "mono": self._clock(),
                "wall": time.time(), "ttl_ms": self.config.ttl_ms,
                "config_hash": self.config.config_hash, "instance": self.config.instance,
                "boot": self._boot, **body}

    def _put(self, publisher, key: str, payload: bytes, attachment: bytes | None = None) -> bool:
        matched = publisher.matching_status.matching
        try:
            publisher.put(payload, attachment=attachment)
        except Exception:  # a failed put is counted and reported in status, never raised
            with self._lock:
                self._counters["errors"][key] += 1
            return False
        with self._lock:
            self._counters["puts"][key] += 1
            if not matched:
                self._counters["unmatched"][key] += 1
        return matched

    def _put_command(self, command: Command, heartbeat: bool) -> int:
        with self._cmd_lock:
            return self._put_command_locked(command, heartbeat)

    def _put_command_locked(self, command: Command, heartbeat: bool) -> int:
        with self._lock:
            body = self._envelope(self.keys.command, COMMAND_SCHEMA,
                                  {**command.to_dict(), "heartbeat": heartbeat})
            if heartbeat:
                self._heartbeats += 1
        self._put(self._pub_command, self.keys.command, json.dumps(body).encode())
        return body["seq"]

    def publish_command(self, command: Command) -> int | None:
        """Hand in the policy's newest command (call every step). It goes out at once when it
        differs from the last one sent (or carries a reset outcome); otherwise the heartbeat
        repeats it. Returns the seq sent, or None when left to the heartbeat."""
        with self._cmd_lock:  # decide and send as one step: concurrent callers stay ordered
            with self._lock:
                self._latest = command
                self._latest_time = self._clock()
                changed = not command.same_as(self._published) or command.reset is not None
                if changed:
                    self._published = command
                if command.reset is not None:
                    self._last_reset = {**command.reset.__dict__, "wall": time.time()}
            if not changed:
                return None
            return self._put_command_locked(command, heartbeat=False)

    def _heartbeat_command(self) -> Command:
        now = self._clock()
        with self._lock:
            latest, when = self._latest, self._latest_time
        if latest is None:
            return Command(STOP, 0.0, (Reason("startup", "monitor has not decided yet"),),
                           since=self._started_mono)
        if when is None or now - when > self.config.stall_timeout:
            cmd = Command(STOP, 0.0, (Reason(
                "stalled", f"pipeline handed in no command for {now - when:.2f} s"),), since=now)
            with self._lock:
                if self._published is None or self._published.state != STOP:
                    self._published = cmd
            return cmd
        return Command(latest.state, latest.speed_scale, latest.reasons, latest.since,
                       latest.latched)

    def _heartbeat_loop(self) -> None:
        period = 1.0 / self.config.heartbeat_hz
        deadline = self._clock()
        while True:
            deadline += period
            delay = deadline - self._clock()
            if delay < -period:  # fell behind (machine paused): restart the grid
                deadline, delay = self._clock(), 0.0
            if self._stop.wait(max(0.0, delay)):
                return
            try:
                self._put_command(self._heartbeat_command(), heartbeat=True)
            except Exception:  # keep beating; the failure is counted by _put
                with self._lock:
                    self._counters["errors"]["heartbeat"] += 1

    def publish_alert(self, alert: Alert) -> bool:
        """Publish an alert unless its kind is rate-limited (then it is counted and its repeat
        count rides on the next one). The JPEG snapshot, if any, is the sample attachment."""
        with self._lock:
            repeat = self._limiter.admit(alert, self._clock())
            if repeat is None:
                return False
            body = self._envelope(self.keys.alert, ALERT_SCHEMA, alert_to_dict(alert, repeat))
        self._put(self._pub_alert, self.keys.alert, json.dumps(body, default=str).encode(),
                  attachment=alert.snapshot_jpeg or None)
        return True

    def publish_detections(self, persons: Persons | None = None,
                           zone_report: ZoneReport | None = None, **extra) -> None:
        """Per processed frame, for dashboards (may be dropped under congestion)."""
        with self._lock:
            body = self._envelope(self.keys.detections, DETECTIONS_SCHEMA,
                                  {**detections_body(persons, zone_report), **extra})
        self._put(self._pub_detections, self.keys.detections, json.dumps(body).encode())

    def update_status(self, **fields) -> None:
        """Merge fields (e.g. fps=12.5, cameras={...}) into what the status queryable answers."""
        with self._lock:
            self._status_extra.update(fields)

    def poll_resets(self) -> list[ResetRequest]:
        """Reset requests received since the last call (oldest first)."""
        with self._lock:
            out = list(self._resets)
            self._resets.clear()
        return out

    def status(self) -> dict:
        """What the ``safety/status`` queryable answers."""
        now = self._clock()
        with self._lock:
            latest = self._latest
            return {
                "schema": STATUS_SCHEMA, "instance": self.config.instance, "boot": self._boot,
                "config_hash": self.config.config_hash, "uptime_s": now - self._started_mono,
                "started_wall": self._started_wall, "wall": time.time(),
                "state": latest.state if latest else STOP,
                "command": latest.to_dict() if latest else None,
                "last_reset": self._last_reset, "heartbeat_hz": self.config.heartbeat_hz,
                "ttl_ms": self.config.ttl_ms, "heartbeats": self._heartbeats,
                "puts": dict(self._counters["puts"]),
                "puts_unmatched": dict(self._counters["unmatched"]),
                "put_errors": dict(self._counters["errors"]),
                "resets_invalid": self._resets_invalid, "alerts_held": self._limiter.held(),
                "fps": None,  # set by the service with update_status(fps=...)
                **self._status_extra,
            }

    # --- callbacks (Zenoh threads) ---------------------------------------------------------

    def _on_status_query(self, query: zenoh.Query) -> None:
        with contextlib.suppress(Exception):  # a vanished querier must not kill the callback
            query.reply(self.keys.status, json.dumps(self.status(), default=str).encode(),
                        encoding="application/json")

    def _on_reset(self, sample: zenoh.Sample) -> None:
        try:
            req = parse_reset(sample.payload.to_bytes(), self._clock())
        except (ValueError, UnicodeDecodeError):
            with self._lock:
                self._resets_invalid += 1
            return
        with self._lock:
            self._resets.append(req)


# --- consumer side --------------------------------------------------------------------------


@dataclass(frozen=True)
class Verdict:
    """What a controller following the consumer rule should do now."""

    state: str
    speed_scale: float
    reason: str  # "" when the monitor's command is followed as is
    seq: int | None = None
    command: dict | None = None
    code: str = ""  # "", "no_command", "ttl", "sequence", "liveliness": stable, for machines


class CommandWatchdog:
    """The consumer-side rule (pure; ``now`` on the consumer's monotonic clock, seconds).

    STOP unless the newest valid command arrived less than its ``ttl_ms`` ago (capped by
    ``max_ttl_ms``), its ``seq`` grew within the same ``boot``, and the monitor's liveliness
    token is present. A command whose seq goes backwards is dropped and forces STOP until a
    newer one arrives. Robot-controller integrators port this class (see docs/consumer.md).
    """

    def __init__(self, max_ttl_ms: float | None = None, instance: str | None = None,
                 require_liveliness: bool = True) -> None:
        self.max_ttl_ms = max_ttl_ms
        self.instance = instance
        self.require_liveliness = require_liveliness
        self.last: dict | None = None
        self.received: float | None = None
        self.boot: str | None = None
        self.seq_error: str | None = None
        self.alive: set[str] = set()
        self.seen_alive: set[str] = set()
        self.rejected = collections.Counter()

    def on_command(self, payload: bytes, now: float) -> str | None:
        """Feed one received payload; returns why it was rejected, or None."""
        try:
            body = json.loads(payload)
            if body.get("schema") != COMMAND_SCHEMA:
                raise ValueError("schema")
            seq, boot, state = int(body["seq"]), str(body["boot"]), body["state"]
            ttl = float(body["ttl_ms"])
            scale = float(body["speed_scale"])
            if state not in ("RUN", "SLOW", "STOP") or not (0 <= scale <= 1) or ttl <= 0:
                raise ValueError("values")
        except (ValueError, KeyError, TypeError, AttributeError):
            self.rejected["invalid"] += 1
            return "invalid"
        if self.instance is not None and body.get("instance") != self.instance:
            self.rejected["other_instance"] += 1
            return "other_instance"
        if self.last is not None and boot == self.boot and seq <= int(self.last["seq"]):
            self.seq_error = f"seq went backwards ({seq} after {self.last['seq']})"
            self.rejected["seq"] += 1
            return "seq"
        self.last, self.received, self.boot, self.seq_error = body, now, boot, None
        return None

    def on_liveliness(self, key: str, alive: bool) -> None:
        instance = key.rsplit("/", 1)[-1]
        if alive:
            self.alive.add(instance)
            self.seen_alive.add(instance)
        else:
            self.alive.discard(instance)

    def verdict(self, now: float) -> Verdict:
        last = self.last
        if last is None:
            return Verdict(STOP, 0.0, "silence: no command received yet", code="no_command")
        seq = int(last["seq"])
        if self.seq_error:
            return Verdict(STOP, 0.0, f"sequence: {self.seq_error}", seq, last, "sequence")
        ttl = float(last["ttl_ms"])
        if self.max_ttl_ms is not None:
            ttl = min(ttl, self.max_ttl_ms)
        age_ms = (now - (self.received or 0.0)) * 1000.0
        if age_ms > ttl:
            return Verdict(STOP, 0.0, f"silence: last command {age_ms:.0f} ms ago "
                           f"(ttl {ttl:.0f} ms)", seq, last, "ttl")
        inst = str(last.get("instance", ""))
        if self.require_liveliness and inst not in self.alive:
            why = "vanished" if inst in self.seen_alive else "not seen"
            return Verdict(STOP, 0.0, f"silence: liveliness token of {inst} {why}", seq, last,
                           "liveliness")
        return Verdict(last["state"], float(last["speed_scale"]), "", seq, last)
