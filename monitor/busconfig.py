"""Zenoh session settings of the bus: ``BusConfig`` (the ``[bus]`` config section), the key
expressions, the Zenoh config built from them, and opening a session with one-line errors."""

from __future__ import annotations

import json
import math
import os
import re
import socket
from dataclasses import dataclass, field

import zenoh

from monitor.errors import ConfigError

MODES = ("peer", "client", "router")


@dataclass(frozen=True)
class BusConfig:
    """Where and how the monitor talks Zenoh. Times in ms unless the name says otherwise.

    ``zenoh_config_file`` (JSON5) is the base; the fields set here override it (None = keep the
    file's value). Without a file: mode peer, multicast scouting off.
    """

    cell: str = "cell1"
    prefix: str | None = None  # default f"workcell/{cell}/"
    instance: str = field(default_factory=lambda: default_instance("monitor"))
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
    signing_key: str | None = None  # Ed25519 private key (PEM, 0600) that signs commands
    operators_file: str | None = None  # "<operator> ed25519:<base64>" per line: who may reset
    allow_unsigned_resets: bool = False  # closed lab setups only: accept resets without keys
    reset_window_s: float = 30.0  # a reset's wall time must be this close to the monitor's
    reset_answer_s: float = 2.0  # a verified reset the policy did not decide on is refused

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
        for name in ("reset_window_s", "reset_answer_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 < value <= 600):
                raise ConfigError(f"bus.{name}: {value!r} not within (0, 600] seconds")

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
        raise ConfigError(f"{bus.zenoh_config_file}: not a valid Zenoh config: "
                          f"{_zenoh_error(exc)}") from None

    def put(key: str, value) -> None:
        try:
            conf.insert_json5(key, json.dumps(value))
        except Exception as exc:
            raise ConfigError(f"bus: Zenoh rejects {key}={value!r}: {_zenoh_error(exc)}"
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
                          f"{_zenoh_error(exc)}") from None


def _zenoh_error(exc: Exception) -> str:
    """Zenoh's error text without its Rust source paths and chained context (one line)."""
    msg = re.search(r'msg: "([^"\n]*)', str(exc))
    text = msg.group(1) if msg else (str(exc).splitlines()[0] if str(exc) else "failed")
    cut = text.find(" at /")
    text = text[:cut] if cut > 0 else text
    if "Address already in use" in str(exc) or "address in use" in str(exc).lower():
        return "the port is already in use (is another monitor or router running?)"
    return text.split(". at ")[0].strip()[:200]
