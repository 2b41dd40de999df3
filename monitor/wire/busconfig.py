"""Zenoh session settings of the bus: ``BusConfig`` (the ``[bus]`` config section), the key
expressions, the Zenoh config built from them, and opening a session with one-line errors."""

from __future__ import annotations

import json
import os
import re
import socket
from dataclasses import dataclass, field
from typing import Annotated, Literal

import zenoh
from pydantic import AfterValidator, Field, model_validator

from monitor.errors import ConfigError
from monitor.schema import Bool, ConfigPath, Float, Int, Seconds, Text, section

MODES = ("peer", "client", "router")


def _key_chunk(value: str) -> str:
    if not value or any(c in value for c in "/*$?#"):
        raise ValueError(f"{value!r} must be a non-empty key chunk (no / * $ ? #)")
    return value


KeyChunk = Annotated[Text, AfterValidator(_key_chunk)]

# chunks under ``safety/`` that are keys of their own: a role by one of these names would mix
# its keys with the cell's (``safety/<role>/...``)
RESERVED_ROLES = frozenset({"alive", "alert", "case", "command", "detections", "holds",
                            "incidents", "mute", "objects", "preview", "reset", "status",
                            "zones"})


def checked_role(value: str) -> str:
    """A monitor's role in the cell ("" = the single monitor of the cell, today's keys)."""
    if value == "":
        return value
    _key_chunk(value)
    if value in RESERVED_ROLES or len(value) > 64:
        raise ValueError(f"{value!r} is not a role name (at most 64 characters, none of "
                         f"{', '.join(sorted(RESERVED_ROLES))})")
    return value


Role = Annotated[Text, AfterValidator(checked_role)]
WithinTenMinutes = Annotated[Float, Field(gt=0, le=600)]


@section("bus")
class BusConfig:
    """Where and how the monitor talks Zenoh. Times in ms unless the name says otherwise.

    ``zenoh_config_file`` (JSON5) is the base; the fields set here override it (None = keep the
    file's value). Without a file: mode peer, multicast scouting off.
    """

    cell: KeyChunk = "cell1"
    prefix: Text | None = None  # default f"workcell/{cell}/"
    instance: KeyChunk = field(default_factory=lambda: default_instance("monitor"))
    # this monitor's role in a cell watched by several monitors (e.g. "monitor-a"): its keys
    # are safety/<role>/... and its liveliness token safety/alive/<role>/<instance>; consumers
    # expect each role with its own key (docs/consumer.md). "" = the cell's only monitor.
    role: Role = ""
    mode: Literal["peer", "client", "router"] | None = None  # None = file's value or peer
    listen: tuple[Text, ...] = ()
    connect: tuple[Text, ...] = ()
    multicast_scouting: Bool = False
    zenoh_config_file: ConfigPath = None
    tls_root_ca: ConfigPath = None  # CA that signed the other side's certificate
    tls_cert: ConfigPath = None  # this side's certificate (listen side, and client for mTLS)
    tls_key: ConfigPath = None
    tls_mutual: Bool | None = None
    user: Text | None = None
    password: Text | None = None
    heartbeat_hz: Annotated[Float, Field(ge=0.1, le=1000)] = 10.0
    ttl_ms: Annotated[Int, Field(gt=0)] = 300  # consumers treat an older command as STOP
    stall_timeout: Seconds = 0.5  # s without publish_command -> heartbeat sends STOP "stalled"
    # bounded wait of BLOCK congestion control before the link closes
    block_wait_ms: Annotated[Int, Field(gt=0)] = 50
    # link lease: a hung peer's liveliness token vanishes after it
    lease_ms: Annotated[Int, Field(gt=0)] | None = 2000
    config_hash: Text = ""
    signing_key: ConfigPath = None  # Ed25519 private key (PEM, 0600) that signs commands
    operators_file: ConfigPath = None  # "<operator> ed25519:<base64>" per line: who may reset
    allow_unsigned_resets: Bool = False  # closed lab setups only: accept resets without keys
    # "<selector> ed25519:<base64>" per line: who may select zone sets (docs/cases.md); None:
    # every selection is refused (and is a STOP fault)
    selectors_file: ConfigPath = None
    case_window_s: WithinTenMinutes = 5.0  # a selection's wall time must be this close to ours
    reset_window_s: WithinTenMinutes = 30.0  # a reset's wall time must be this close to ours
    # a verified reset the policy did not decide on is refused after this
    reset_answer_s: WithinTenMinutes = 2.0

    @model_validator(mode="after")
    def _rules(self) -> BusConfig:
        if self.ttl_ms <= 1000.0 / self.heartbeat_hz:
            raise ValueError(f"ttl_ms: {self.ttl_ms} must exceed the heartbeat period "
                             f"{1000.0 / self.heartbeat_hz:.0f} ms")
        if (self.user is None) != (self.password is None):
            raise ValueError("user/password: give both or neither")
        if (self.tls_cert is None) != (self.tls_key is None):
            raise ValueError("tls_cert/tls_key: give both or neither")
        return self

    @property
    def key_prefix(self) -> str:
        prefix = self.prefix if self.prefix is not None else f"workcell/{self.cell}/"
        return prefix if prefix.endswith("/") else prefix + "/"


_PROCESS_TOKEN = os.urandom(2).hex()  # one per process: equal configs compare equal


def default_instance(role: str) -> str:
    """A unique instance id: role, host, pid and a random part drawn once per process (two
    monitors never share one by accident, even across containers with equal pids)."""
    host = "".join(c if c.isalnum() or c in "-_." else "-" for c in socket.gethostname())
    return f"{role}-{host or 'host'}-{os.getpid()}-{_PROCESS_TOKEN}"


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
    mute: str = ""  # signed mute requests (monitor.cases.mute_requests; docs/muting.md)
    zones_apply: str = ""  # signed zone applies (monitor.cases.zone_apply)
    holds: str = ""  # signed holds of persons lost inside zones (monitor.bus.holds)
    case: str = ""  # signed zone set selections, one key per cell (monitor.cases.receiver)
    preview: str = ""  # small live pictures per camera for the console (monitor.bus.preview)
    # signed acceptances of objects since commissioning (monitor.wire.object_accepts)
    objects_accept: str = ""
    role: str = ""

    @classmethod
    def of(cls, prefix: str, role: str = "") -> BusKeys:
        """The keys of the monitor with ``role`` under ``prefix``: role "" (the cell's only
        monitor) keeps ``safety/command`` ...; a role puts its own under ``safety/<role>/``
        and its liveliness tokens under ``safety/alive/<role>/``. The tool pose and the zone
        set selection are the cell's, shared by all roles."""
        p = prefix if prefix.endswith("/") else prefix + "/"
        s = p + "safety/" + (f"{role}/" if role else "")
        return cls(command=s + "command", alert=s + "alert",
                   detections=s + "detections", status=s + "status",
                   reset=s + "reset", alive=p + "safety/alive" + (f"/{role}" if role else ""),
                   pose=p + "tracker/pose", mute=s + "mute", zones_apply=s + "zones/apply",
                   holds=s + "holds", case=p + "safety/case", preview=s + "preview",
                   objects_accept=s + "objects/accept", role=role)


def zenoh_config(bus: BusConfig) -> zenoh.Config:
    """Build the Zenoh session config from the service's bus config."""
    try:
        conf = (zenoh.Config.from_file(bus.zenoh_config_file) if bus.zenoh_config_file
                else zenoh.Config())
    except Exception as exc:
        raise ConfigError(f"{bus.zenoh_config_file}: not a valid Zenoh config: "
                          f"{zenoh_error(exc)}") from None

    def put(key: str, value) -> None:
        try:
            conf.insert_json5(key, json.dumps(value))
        except Exception as exc:
            raise ConfigError(f"bus: Zenoh rejects {key}={value!r}: {zenoh_error(exc)}"
                              ) from None

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
                          f"listen={list(bus.listen)}, connect={list(bus.connect)}): "
                          f"{zenoh_error(exc)}") from None


def zenoh_error(exc: Exception) -> str:
    """Zenoh's error text without its Rust source paths and chained context (one line)."""
    msg = re.search(r'msg: "([^"\n]*)', str(exc))
    text = msg.group(1) if msg else (str(exc).splitlines()[0] if str(exc) else "failed")
    cut = text.find(" at /")
    text = text[:cut] if cut > 0 else text
    if "Address already in use" in str(exc) or "address in use" in str(exc).lower():
        return "the port is already in use (is another monitor or router running?)"
    return text.split(". at ")[0].strip()[:200]
