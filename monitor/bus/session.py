"""Zenoh bus of the monitor: commands, heartbeat, alerts, detections, status, resets, liveliness.

Keys (``prefix`` defaults to ``workcell/<cell>/``):

=================================  =========================================================
``<prefix>safety/command``          RUN/SLOW/STOP; on every change and as a heartbeat at
                                    ``heartbeat_hz``. Priority REAL_TIME, express, BLOCK
                                    with a bounded wait (``block_wait_ms``).
``<prefix>safety/alert``            alerts (JSON; JPEG snapshot as the sample attachment)
``<prefix>safety/detections``       persons and zone hits per processed frame (dashboards)
``<prefix>safety/preview``          a small signed JPEG per camera at a low rate, published by
                                    ``monitor.bus.preview`` on its own publisher (the console)
``<prefix>safety/status``           queryable: state, config hash, fps, uptime, last reset
``<prefix>safety/reset``            queryable (and subscribed): signed operator resets
                                    (``monitor.wire.resets``); the reply is the answer
``<prefix>safety/mute``             queryable: signed mute requests
                                    (``monitor.cases.mute_requests``; docs/muting.md)
``<prefix>safety/zones/apply``     queryable: signed zone applies (``monitor.service.zone_swap``)
``<prefix>safety/objects/accept``  queryable: signed acceptances of objects since commissioning
                                    (``monitor.wire.object_accepts``; docs/occlusion.md)
``<prefix>safety/alive/<instance>`` liveliness token of the running monitor
``<prefix>tracker/pose``            tool pose samples (``monitor.pose.stream``)
=================================  =========================================================

Every payload is a UTF-8 JSON object with the envelope ``schema`` (e.g.
``workcell.safety.command/1``), ``seq`` (per key, +1 per message, from 1 in each session),
``cell``, ``mono`` (sender's monotonic clock, s), ``wall`` (sender's Unix time, s), ``ttl_ms``,
``config_hash``, ``instance`` and ``boot`` (the Zenoh session id: a new one after a restart).

A subscriber that stops reading (hung controller, full TCP buffers) costs a command put at most
``block_wait_ms`` (Zenoh's ``wait_before_close``); then Zenoh gives up on that link instead of
stalling the monitor for its default 5 s. Puts that reach no subscriber and failed puts are counted
and reported by the status queryable (``puts_unmatched``, ``put_errors``).

Signing (``monitor.wire.signing``): with ``signing_key`` set, every command and heartbeat carries an
Ed25519 signature of its exact payload bytes as the sample attachment; the payload holds cell,
instance, boot, seq, state, speed_scale, ttl_ms, mono and wall. Resets are queries on
``safety/reset`` signed by an operator key listed in ``operators_file``; the bus refuses the
others itself (answered to the sender, alerted) and hands the pipeline only verified requests
(``monitor.wire.resets``; the bus's side: ``monitor.bus.reset_desk.ResetDesk``). The policy's
outcome is the answer to the query.

Several monitors per cell (``BusConfig.role``, docs/consumer.md): a monitor with a role has its
keys under ``<prefix>safety/<role>/`` (command, alert, detections, status, reset, mute, zones
apply) and its token under ``<prefix>safety/alive/<role>/<instance>``; role "" keeps the keys
above. Consumers expect each role with its key (``monitor.wire.cell_consumer.CellWatchdog``).

One monitor per cell (per role): the instance id is unique by default (host, pid, random); at
start the bus refuses to run when another monitor's liveliness token is present on the cell, and
later it reports ``duplicate_monitor`` (``faults()``) and sends STOP while another monitor's
token or commands are seen. Only commands signed with this cell's monitor key count as another
monitor's; unsigned or wrongly signed ones are counted and alerted (``monitor.bus.foreign``). The
bus's side: ``monitor.bus.peers.PeerWatch``.

Consumer rule: ``monitor.wire.consumer.CommandWatchdog`` (shown by ``monitor watch``;
docs/consumer.md).
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import json
import logging
import threading
import time
from collections.abc import Callable

import zenoh

from monitor.bus.accept_desk import AcceptDesk
from monitor.bus.peers import DuplicateMonitor, PeerWatch
from monitor.bus.reset_desk import RESET_ANSWER_SCHEMA, ResetDesk
from monitor.cases.mute_requests import MuteDesk, MuteGate
from monitor.cases.muting import MuteOutcome, MuteRequest
from monitor.policy import STOP, Command, Reason, ResetRequest
from monitor.signals import close_bounded
from monitor.types import Alert, Fault, Persons, ZoneReport
from monitor.wire.alerts import AlertLimiter, AlertLimits, alert_to_dict, signed_attachment
from monitor.wire.answers import answer_attachment, request_digest
from monitor.wire.busconfig import (
    MODES,
    BusConfig,
    BusKeys,
    default_instance,
    open_session,
    zenoh_config,
    zenoh_error,
)
from monitor.wire.consumer import COMMAND_SCHEMA, CommandWatchdog, Verdict
from monitor.wire.object_accepts import AcceptGate, AcceptOutcome, ObjectAccept
from monitor.wire.resets import RESET_SCHEMA, ResetGate, ResetPolicy, latch_of, reset_payload
from monitor.wire.signing import Signer, load_operators, load_private_key

_log = logging.getLogger("monitor.bus.session")

__all__ = [
    "COMMAND_SCHEMA",
    "MODES",
    "RESET_ANSWER_SCHEMA",
    "RESET_SCHEMA",
    "BusConfig",
    "BusKeys",
    "CommandWatchdog",
    "DuplicateMonitor",
    "SafetyBus",
    "Verdict",
    "default_instance",
    "open_session",
    "reset_payload",
    "zenoh_config",
    "zenoh_error",
]

SCHEMA_VERSION = 1
ALERT_SCHEMA = f"workcell.safety.alert/{SCHEMA_VERSION}"
DETECTIONS_SCHEMA = f"workcell.safety.detections/{SCHEMA_VERSION}"
STATUS_SCHEMA = f"workcell.safety.status/{SCHEMA_VERSION}"
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
    (bounded) and a last STOP (reason ``shutdown``) goes out first.

    Thread-safe: the pipeline calls ``publish_command`` per step; the heartbeat thread
    re-publishes the latest command at ``heartbeat_hz``.
    """

    def __init__(self, config: BusConfig, *, alert_limits: AlertLimits | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 startup_check_s: float = 1.0) -> None:
        self.config = config
        self.keys = BusKeys.of(config.key_prefix, config.role)
        self._clock = clock
        self._startup_check_s = startup_check_s
        self._signer: Signer | None = (load_private_key(config.signing_key)
                                       if config.signing_key else None)
        operators = load_operators(config.operators_file) if config.operators_file else None
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
        # resets share the bus's lock: checked against the latch published at that moment
        self._resets = ResetDesk(
            ResetGate(ResetPolicy(operators, config.cell, self.keys.reset,
                                  config.allow_unsigned_resets, config.reset_window_s)),
            self.keys.reset, config.reset_answer_s, clock, self._lock, self._signer,
            {"instance": config.instance})
        # mutes and acceptances answer signed, naming the monitor as resets do (the same
        # ``who``: its boot is set once the session is open)
        self._mutes = MuteDesk(MuteGate(operators, config.cell, self.keys.mute,
                                        config.reset_window_s), config.reset_answer_s,
                               self._signer, self._resets.who)
        self._accepts = AcceptDesk(AcceptGate(operators, config.cell, self.keys.objects_accept,
                                              config.reset_window_s), config.reset_answer_s,
                                   self._signer, self._resets.who)
        self._peers = PeerWatch(
            cell=config.cell, role=config.role, instance=config.instance,
            alive_key=self.keys.alive, command_key=self.keys.command,
            public_key=self._signer.key.public_key() if self._signer else None, clock=clock)
        self._status_extra: dict = {}
        self._next_config_hash: str | None = None  # a signed zone apply, from the next command
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._session: zenoh.Session | None = None
        self._entities: list = []
        self._boot = ""
        self._started_mono = clock()
        self._started_wall = time.time()
        self._heartbeats = 0
        self.closed_cleanly: bool | None = None

    # --- lifecycle ---------------------------------------------------------------------------

    def __enter__(self) -> SafetyBus:
        self._session = open_session(self.config)
        try:
            s = self._session
            self._boot = str(s.zid())
            self._resets.who["boot"] = self._boot
            self._peers.refuse_if_another(s, self._startup_check_s)
            self._pub_command = s.declare_publisher(
                self.keys.command, encoding="application/json",
                priority=zenoh.Priority.REAL_TIME, express=True,
                congestion_control=zenoh.CongestionControl.BLOCK,
                # remote only: our own duplicate-monitor subscriber below must not count as a
                # consumer in matching_status (unmatched puts are reported)
                allowed_destination=zenoh.Locality.REMOTE)
            self._pub_alert = s.declare_publisher(
                self.keys.alert, encoding="application/json",
                priority=zenoh.Priority.DATA_HIGH, congestion_control=zenoh.CongestionControl.DROP)
            self._pub_detections = s.declare_publisher(
                self.keys.detections, encoding="application/json",
                priority=zenoh.Priority.DATA, congestion_control=zenoh.CongestionControl.DROP)
            self._entities = [
                s.declare_queryable(self.keys.status, self._on_status_query),
                s.declare_queryable(self.keys.reset, lambda q: self._resets.on_query(
                    q, self._boot, self._latch_now)),
                s.declare_subscriber(self.keys.reset, lambda sample: self._resets.on_sample(
                    sample, self._boot, self._latch_now)),
                s.declare_queryable(self.keys.mute, self._on_mute_query),
                s.declare_queryable(self.keys.objects_accept, self._on_accept_query),
                s.declare_subscriber(self.keys.command,
                                     lambda sample: self._peers.on_command(sample, self._boot),
                                     allowed_origin=zenoh.Locality.REMOTE),
                s.liveliness().declare_subscriber(self.keys.alive + "/*", self._peers.on_alive),
            ]
            self._token = s.liveliness().declare_token(f"{self.keys.alive}/{self.config.instance}")
            self._thread = threading.Thread(target=self._heartbeat_loop, name="bus-heartbeat",
                                            daemon=True)
            self._thread.start()
        except BaseException:
            close_bounded(self._session, 1.0, self._entities)
            self._session = None
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self, timeout: float = 1.0) -> None:
        """Stop the heartbeat, send STOP (shutdown), close the session within ``timeout``.
        Idempotent. ``closed_cleanly`` says whether Zenoh's close finished in time."""
        if self._session is None:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        session, self._session = self._session, None
        try:
            self._put_command(Command(STOP, 0.0, (Reason("shutdown", "monitor shutting down"),),
                                      since=self._clock()), heartbeat=False)
        except Exception:
            with self._lock:
                self._counters["errors"]["shutdown"] += 1
        finally:
            self._resets.answer_all("the monitor is shutting down")
            self._mutes.answer_all("the monitor is shutting down")
            self._accepts.answer_all("the monitor is shutting down")
            self.closed_cleanly = close_bounded(session, timeout, [*self._entities, self._token])

    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("SafetyBus is not open (use it as a context manager)")
        return self._session

    @property
    def boot(self) -> str:
        return self._boot

    def signed_answer(self, key_expr: str, body: dict, digest: str
                      ) -> tuple[bytes, bytes | None]:
        """An answer to the request whose SHA-256 is ``digest`` on ``key_expr``, as the desks
        write theirs (``monitor.wire.answers``): ``body``, this monitor's instance and boot and
        the request it answers, and its signature (None: the monitor has no key). For the
        queryables the bus does not own (zone applies, zone sets) and its status."""
        answer = json.dumps({**body, **self._resets.who, "request": digest},
                            default=str).encode()
        return answer, answer_attachment(self._signer, key_expr, answer)

    @property
    def public_key(self) -> str | None:
        """The ``ed25519:<base64>`` key consumers pin, or None when commands are unsigned."""
        return self._signer.public_text if self._signer else None

    def pose_subscriber(self, limits=None, on_reject=None, tracker_clock=None, tracker=None):
        """A ``monitor.pose.stream.PoseSubscriber`` on ``<prefix>tracker/pose`` of this session
        (use it as a context manager inside the bus's ``with``); ``tracker_clock``: the
        ``[tracker_clock]`` settings its tracker times are checked with; ``tracker``: the
        ``[tracker]`` precision its pose checks allow for."""
        from monitor.pose.stream import PoseSubscriber

        return PoseSubscriber(self.session, self.keys.pose, limits, self._clock, on_reject,
                              tracker_clock=tracker_clock, tracker=tracker)

    # --- one monitor per cell (monitor.bus.peers) ------------------------------------------

    def faults(self) -> list[Fault]:
        """Faults the bus sees (poll every step): ``duplicate_monitor`` while another monitor's
        liveliness token or commands (within the last 2 s) are seen on this cell."""
        return self._peers.faults()

    def foreign_commands(self) -> dict[str, int]:
        """Commands on our key ignored per kind (unsigned, signature, ...;
        ``monitor.bus.foreign``)."""
        return self._peers.foreign_counts()

    # --- publishing --------------------------------------------------------------------------

    def _envelope(self, key: str, schema: str, body: dict) -> dict:
        self._seq[key] += 1
        return {"schema": schema, "cell": self.config.cell, "seq": self._seq[key],
                "mono": self._clock(), "wall": time.time(), "ttl_ms": self.config.ttl_ms,
                "config_hash": self.config.config_hash, "instance": self.config.instance,
                "boot": self._boot, **({"role": self.config.role} if self.config.role else {}),
                **body}

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
        command = self._peers.guarded(command)
        with self._lock:
            # boot_wall orders boots: a consumer drops an older boot's commands for good
            body = self._envelope(self.keys.command, COMMAND_SCHEMA,
                                  {**command.to_dict(), "heartbeat": heartbeat,
                                   "boot_wall": self._started_wall})
            if heartbeat:
                self._heartbeats += 1
        payload = json.dumps(body).encode()
        signature = self._signer.sign(self.keys.command, payload) if self._signer else None
        self._put(self._pub_command, self.keys.command, payload, signature)
        return body["seq"]

    def publish_command(self, command: Command, decided_at: float | None = None) -> int | None:
        """Hand in the policy's newest command (call every step). It goes out at once when it
        differs from the last one sent (or carries a reset outcome); otherwise the heartbeat
        repeats it. Returns the seq sent, or None when left to the heartbeat. A reset outcome
        is also the answer to that reset's query (``monitor reset`` waits for it).

        ``decided_at`` (this bus's clock): when the policy decided it. A command older than
        ``stall_timeout`` by now was decided before the process froze (between the decision
        and this call): it says nothing about the cell now, so a "stalled" STOP goes out in
        its place, as the heartbeat would send after the same silence."""
        if decided_at is not None and command.state != STOP:
            age = self._clock() - decided_at
            if age > self.config.stall_timeout:
                command = Command(STOP, 0.0, (Reason(
                    "stalled", f"command decided {age:.2f} s before it could be published "
                    f"(limit {self.config.stall_timeout:g} s): the monitor was frozen"),),
                    since=self._clock(), reset=command.reset)
        with self._cmd_lock:  # decide and send as one step: concurrent callers stay ordered
            with self._lock:
                new_zones = self._next_config_hash is not None
                if new_zones:
                    self.config = dataclasses.replace(self.config,
                                                      config_hash=self._next_config_hash)
                    self._next_config_hash = None
                self._latest = command
                self._latest_time = self._clock()
                changed = (not command.same_as(self._published) or command.reset is not None
                           or new_zones)
                if changed:
                    self._published = command
                if command.reset is not None:
                    self._resets.last_reset = {**command.reset.__dict__, "wall": time.time()}
            seq = self._put_command_locked(command, heartbeat=False) if changed else None
        if command.reset is not None:
            r = command.reset
            self._resets.answer(r.request_id, r.accepted, r.message, "policy", command.state)
        return seq

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
                    # consumers STOP now: the monitor's own log says so too (once a stall)
                    _log.warning("bus: STOP stalled: the pipeline handed in no command for "
                                 "%.2f s (bus.stall_timeout %g s)", now - when,
                                 self.config.stall_timeout)
            return cmd
        # the whole command (latch cause, reset possible, clear time), without the reset
        # outcome, which is answered once
        return dataclasses.replace(latest, reset=None)

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
                self._resets.expire()
                self._mutes.expire(self._clock())
                self._accepts.expire(self._clock())
                self._flush_refused_alerts()
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
        payload = json.dumps(body, default=str).encode()
        # signed like the commands (with the snapshot's sha256 in the payload): a console
        # lists no alert someone else put here (monitor.wire.alerts)
        signature = self._signer.sign(self.keys.alert, payload) if self._signer else None
        self._put(self._pub_alert, self.keys.alert, payload,
                  attachment=signed_attachment(signature, alert.snapshot_jpeg))
        return True

    def publish_detections(self, persons: Persons | None = None,
                           zone_report: ZoneReport | None = None, **extra) -> None:
        """Per processed frame, for dashboards (may be dropped under congestion)."""
        with self._lock:
            body = self._envelope(self.keys.detections, DETECTIONS_SCHEMA,
                                  {**detections_body(persons, zone_report), **extra})
        self._put(self._pub_detections, self.keys.detections, json.dumps(body).encode())

    def set_config_hash(self, config_hash: str) -> None:
        """The zone set in force changed (a signed apply): from the next command handed in
        (the first decided on it) every message names it; a heartbeat repeating a command
        decided on the old zones never carries the new hash."""
        with self._lock:
            self._next_config_hash = config_hash

    def update_status(self, **fields) -> None:
        """Merge fields (e.g. fps=12.5, cameras={...}) into what the status queryable answers."""
        with self._lock:
            self._status_extra.update(fields)

    # --- resets (monitor.bus.reset_desk) --------------------------------------------------------

    def poll_resets(self) -> list[ResetRequest]:
        """Verified reset requests received since the last call (oldest first). Refused ones
        never appear here: the bus answered and alerted them itself."""
        return self._resets.poll()

    def _latch_now(self) -> str | None:
        """The latch published now (called by the reset desk with the bus's lock held)."""
        return latch_of(self._latest)

    def _flush_refused_alerts(self) -> None:
        alerts = (self._resets.drain_alerts() + self._mutes.drain_alerts()
                  + self._accepts.drain_alerts())
        foreign = self._peers.foreign_alert("bus")
        for alert in [*alerts, *([foreign] if foreign else [])]:
            self.publish_alert(alert)

    # --- mutes -------------------------------------------------------------------------------

    def poll_mutes(self) -> tuple[MuteRequest, ...]:
        """Verified mute requests since the last call, for the pipeline to judge."""
        return self._mutes.poll()

    def answer_mute(self, outcome: MuteOutcome) -> None:
        """The pipeline's judgement of a mute request, as the answer to its query."""
        self._mutes.answer(outcome)

    def _on_mute_query(self, query: zenoh.Query) -> None:
        self._mutes.on_query(query, self._clock(), self._boot)

    # --- acceptances of objects since commissioning (monitor.bus.accept_desk) --------------

    def poll_accepts(self) -> tuple[ObjectAccept, ...]:
        """Verified acceptances since the last call, for the pipeline to judge."""
        return self._accepts.poll()

    def answer_accept(self, outcome: AcceptOutcome) -> None:
        """The pipeline's judgement of an acceptance, as the answer to its query."""
        self._accepts.answer(outcome)

    def _on_accept_query(self, query: zenoh.Query) -> None:
        self._accepts.on_query(query, self._clock(), self._boot)

    # --- status ------------------------------------------------------------------------------

    def status(self) -> dict:
        """What the ``safety/status`` queryable answers."""
        now = self._clock()
        others = self._peers.others()
        with self._lock:
            latest = self._latest
            return {
                "schema": STATUS_SCHEMA, "cell": self.config.cell, "role": self.config.role,
                "instance": self.config.instance, "boot": self._boot,
                "config_hash": self.config.config_hash, "uptime_s": now - self._started_mono,
                "started_wall": self._started_wall, "wall": time.time(),
                "state": latest.state if latest else STOP,
                "command": latest.to_dict() if latest else None,
                "latch": latch_of(latest),  # the nonce a reset must name (None: not latched)
                "last_reset": self._resets.last_reset, "heartbeat_hz": self.config.heartbeat_hz,
                "ttl_ms": self.config.ttl_ms, "heartbeats": self._heartbeats,
                "signed": self._signer is not None, "public_key": self.public_key,
                "other_monitors": others,
                "puts": dict(self._counters["puts"]),
                "puts_unmatched": dict(self._counters["unmatched"]),
                "put_errors": dict(self._counters["errors"]),
                "resets_invalid": self._resets.invalid, "resets_refused": self._resets.refused,
                "mutes_accepted": self._mutes.accepted, "mutes_refused": self._mutes.refused,
                "objects_accepted": self._accepts.accepted,
                "object_accepts_refused": self._accepts.refused,
                # operators' queries waiting for the pipeline's answer (a stalled loop: > 0)
                "resets_waiting": len(self._resets.pending), "mutes_waiting": self._mutes.waiting,
                "commands_foreign": self.foreign_commands(),
                "alerts_held": self._limiter.held(),
                "fps": None,  # set by the service with update_status(fps=...)
                **self._status_extra,
            }

    def _on_status_query(self, query: zenoh.Query) -> None:
        with contextlib.suppress(Exception):  # a vanished querier must not kill the callback
            # signed, naming the query's payload (``monitor status --monitor-key`` sends a
            # nonce): anyone may answer on the status key, and a forged "RUN, all healthy"
            # must not reach an operator who asked the monitor
            request = query.payload.to_bytes() if query.payload is not None else b""
            answer, signature = self.signed_answer(self.keys.status, self.status(),
                                                   request_digest(request))
            query.reply(self.keys.status, answer, encoding="application/json",
                        attachment=signature)

