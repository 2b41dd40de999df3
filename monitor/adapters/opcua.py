"""`monitor bridge opcua`: the safety snapshot as read-only variables of an OPC UA server.

The server (asyncua) runs on its own thread with its own asyncio loop. ``publish`` only hands
the newest snapshot over (never blocks the follower); the loop thread writes the variables,
state variables first when the state gets safer and last when it gets less safe, so a client
never reads RUN beside the reasons of a STOP. If no snapshot arrives for ``stale_ms`` (the
follower is stuck), the loop thread itself writes STOP (``adapter_stale``): the outputs fail
towards STOP, and the heartbeat and the snapshot time stop changing for clients to see.

Nobody can write: every variable is CurrentRead only, and the permission rules refuse Write
and Call requests for every user (BadUserAccessDenied). The information model, the Machine
Vision (OPC 40100-1) mapping and the security choices are in docs/opcua.md.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import ipaddress
import logging
import threading
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

from monitor.adapters.snapshot import Output, SafetySnapshot
from monitor.errors import ConfigError

log = logging.getLogger("monitor.adapters.opcua")

NAMESPACE = "urn:workcell-monitor:opcua"  # clients resolve the index from this URI
APPLICATION_URI = "urn:workcell-monitor:opcua:server"  # the server certificate's SAN URI
DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840/workcell-monitor"
DEFAULT_STALE_MS = 250.0
DEFAULT_HANDSHAKE_S = 3.0  # a connection without an activated session is closed after this
OBJECT = "WorkcellMonitor"
SSM = "SafetyStateManagement"  # the OPC 40100-1 SafetyStateManagementType's instance name
# the consumer rule's own verdicts (monitor.wire.consumer): nothing is known about cameras then
OVERRIDES = frozenset({"no_command", "ttl", "sequence", "liveliness", "duplicate_monitor",
                       "adapter_stale"})
# written together, first when the state gets safer and last when it gets less safe
STATE_VARS = ("State", "StateName", "SpeedScale", f"{SSM}.VisionSafetyTriggered")


@dataclass(frozen=True)
class Variable:
    name: str  # browse path below WorkcellMonitor, "." between levels
    vtype: str  # asyncua VariantType name
    description: str
    array: bool = False


VARIABLES: tuple[Variable, ...] = (
    Variable("State", "Int32", "the adapter's verdict: 0 STOP, 1 SLOW, 2 RUN"),
    Variable("StateName", "String", "STOP, SLOW or RUN"),
    Variable("SpeedScale", "Double", "0 for STOP; the SLOW scale; 1 for RUN"),
    Variable("Latched", "Boolean", "the last verified command is latched (needs a reset)"),
    Variable("ResetPossible", "Boolean", "a reset would be accepted now"),
    Variable("ReasonCode", "String", "the verdict's override code (no_command, ttl, sequence, "
             "liveliness, duplicate_monitor, adapter_stale) or the command's first reason code"),
    Variable("Reason", "String", "human-readable reason"),
    Variable("ZoneId", "String", "the zone of the first reason ('' none)"),
    Variable("Seq", "Int64", "the last verified command's seq (-1 none)"),
    Variable("Heartbeat", "UInt32", "+1 every adapter tick (wraps at 2^32): unchanged = "
             "adapter frozen, treat as STOP"),
    Variable("CommandAgeMs", "Double", "age of the last verified command at the snapshot "
             "(-1 none)"),
    Variable("SnapshotTime", "DateTime", "the adapter's wall clock when the values were made"),
    Variable("Faults", "String", "fault names among the command's reasons", array=True),
    Variable("CameraIds", "String", "the cameras reported in CamerasOk", array=True),
    Variable("CamerasOk", "Boolean", "per camera of CameraIds: no fault names it", array=True),
    Variable("CameraOk", "Boolean", "a fresh command names no fault at all"),
    Variable("Cell", "String", "the cell of the last verified command"),
    Variable("MonitorInstance", "String", "the monitor instance followed"),
    Variable("ZoneHash", "String", "the command's config_hash: the zone set in force"),
    Variable(f"{SSM}.VisionSafetyTriggered", "Boolean", "OPC 40100-1: the safety function "
             "has acted (State is not RUN)"),
    Variable(f"{SSM}.VisionSafetyInformation", "String", "OPC 40100-1: state, code and "
             "reason as text"),
)


def node_id(name: str) -> str:
    """The string identifier of a variable (in namespace ``NAMESPACE``)."""
    return f"{OBJECT}.{name}"


def values_of(snap: SafetySnapshot, camera_ids: tuple[str, ...]) -> dict[str, Any]:
    """The variable values showing ``snap`` (pure)."""
    overridden = snap.reason_code in OVERRIDES
    cams = [bool(snap.cameras.get(c)) and not overridden for c in camera_ids]
    info = f"{snap.state}: {snap.reason_code or 'clear'}" + (f": {snap.reason}"
                                                             if snap.reason else "")
    return {
        "State": snap.state_code, "StateName": snap.state, "SpeedScale": snap.speed_scale,
        "Latched": snap.latched, "ResetPossible": snap.reset_possible,
        "ReasonCode": snap.reason_code, "Reason": snap.reason, "ZoneId": snap.zone_id or "",
        "Seq": -1 if snap.seq is None else int(snap.seq),
        "Heartbeat": snap.counter % 2**32,
        "CommandAgeMs": -1.0 if snap.age_ms is None else float(snap.age_ms),
        "SnapshotTime": datetime.fromtimestamp(snap.wall, UTC),
        "Faults": list(snap.faults), "CameraIds": list(camera_ids), "CamerasOk": cams,
        "CameraOk": not overridden and not snap.faults and all(cams),
        "Cell": snap.cell, "MonitorInstance": snap.instance, "ZoneHash": snap.zone_hash,
        f"{SSM}.VisionSafetyTriggered": snap.state != "RUN",
        f"{SSM}.VisionSafetyInformation": info[:1000],
    }


def stop_values(values: dict[str, Any], code: str, reason: str) -> dict[str, Any]:
    """``values`` overridden to STOP by the server itself (at start, or the follower stuck);
    the heartbeat and snapshot time are left as they are: they say how old the rest is."""
    out = dict(values)
    out.update({"State": 0, "StateName": "STOP", "SpeedScale": 0.0, "ResetPossible": False,
                "ReasonCode": code, "Reason": reason, "ZoneId": "",
                "CamerasOk": [False] * len(values["CameraIds"]), "CameraOk": False,
                f"{SSM}.VisionSafetyTriggered": True,
                f"{SSM}.VisionSafetyInformation": f"STOP: {code}: {reason}"})
    return out


def stale(snap: SafetySnapshot, now: float, stale_s: float) -> bool:
    """``snap`` is older than ``stale_s`` at ``now`` (the adapter's monotonic clock): the
    follower is stuck and the server shows STOP itself. An age that is not a number is stale."""
    return not now - snap.mono <= stale_s


def next_values(snap: SafetySnapshot | None, now: float, stale_s: float,
                shown: dict[str, Any], last_counter: int | None,
                camera_ids: tuple[str, ...]) -> dict[str, Any] | None:
    """What the variables must show at ``now``, or None when nothing is to be written: no
    snapshot yet (the initial STOP stands), the tick already shown, or a stale spell already
    shown as STOP. A snapshot older than ``stale_s`` is STOP, ``adapter_stale``."""
    if snap is None:
        return None
    if stale(snap, now, stale_s):
        if shown["ReasonCode"] == "adapter_stale":
            return None
        return stop_values(shown, "adapter_stale", "the adapter's loop handed over no "
                           f"snapshot for {stale_s * 1000:.0f} ms")
    if snap.counter == last_counter:
        return None
    return values_of(snap, camera_ids)


def initial_values(camera_ids: tuple[str, ...]) -> dict[str, Any]:
    """What a client reads before the first snapshot: STOP, no command."""
    base = {"Latched": False, "Seq": -1, "Heartbeat": 0, "CommandAgeMs": -1.0,
            "SnapshotTime": datetime.now(UTC), "Faults": [], "CameraIds": list(camera_ids),
            "Cell": "", "MonitorInstance": "", "ZoneHash": ""}
    return stop_values(base, "no_command", "adapter started: no command yet")


def write_order(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """Names of the changed values in write order: the state first when it gets safer (a
    client may read between two writes: it must never see RUN with the rest of a STOP)."""
    changed = [v.name for v in VARIABLES if old.get(v.name) != new[v.name]]
    state = [n for n in changed if n in STATE_VARS]
    rest = [n for n in changed if n not in STATE_VARS]
    safer = (new["State"], new["SpeedScale"]) <= (old.get("State", 0), old.get("SpeedScale", 0))
    return state + rest if safer else rest + state


# --- settings ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class OpcUaSettings:
    endpoint: str = DEFAULT_ENDPOINT
    cert: Path | None = None
    key: Path | None = None
    users: dict = field(default_factory=dict)  # name -> opcua_users.PasswordHash
    anonymous: bool = True
    client_certs: tuple[bytes, ...] | None = None  # DER of trusted client certificates
    max_clients: int = 16
    stale_ms: float = DEFAULT_STALE_MS
    handshake_s: float = DEFAULT_HANDSHAKE_S

    @property
    def secure(self) -> bool:
        return self.cert is not None


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("OPC UA server (docs/opcua.md)")
    g.add_argument("--endpoint", default=DEFAULT_ENDPOINT, metavar="URL",
                   help=f"where the server listens (default {DEFAULT_ENDPOINT}); a non-loopback "
                   "host needs --cert and --key")
    g.add_argument("--cert", type=Path, metavar="FILE",
                   help="server certificate (PEM or DER; SAN URI "
                   f"{APPLICATION_URI}): switches the endpoint to Basic256Sha256 "
                   "SignAndEncrypt only (default none: NoSecurity, loopback only)")
    g.add_argument("--key", type=Path, metavar="FILE",
                   help="the server certificate's private key (PEM or DER; default none)")
    g.add_argument("--users", type=Path, metavar="FILE",
                   help="users file (NAME:pbkdf2-sha256:...; `python -m "
                   "monitor.adapters.opcua_users NAME` makes lines): user/password login, "
                   "read-only like everybody (needs --cert; default none)")
    g.add_argument("--no-anonymous", action="store_true",
                   help="refuse anonymous clients (needs --users; default: anonymous may read)")
    g.add_argument("--client-certs", type=Path, metavar="DIR",
                   help="only clients whose application certificate (.der/.pem) is in DIR "
                   "may open a session (needs --cert; default: any client certificate)")
    g.add_argument("--max-clients", type=int, default=16,
                   help="simultaneous client connections (default 16); a connection without "
                   "an activated session gives its slot to a new one when all are taken")
    g.add_argument("--handshake-s", type=float, default=DEFAULT_HANDSHAKE_S,
                   help="a connection that has not activated a session within this is closed "
                   f"(idle or half-open sockets; default {DEFAULT_HANDSHAKE_S:g})")
    g.add_argument("--stale-ms", type=float, default=DEFAULT_STALE_MS,
                   help="the server writes STOP itself when the adapter's loop handed it no "
                   f"snapshot for this long (default {DEFAULT_STALE_MS:g})")


def _load_der(path: Path, what: str) -> bytes:
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding

    try:
        data = path.read_bytes()
        cert = (x509.load_pem_x509_certificate(data) if b"-----BEGIN" in data
                else x509.load_der_x509_certificate(data))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{what} {path}: not a readable PEM or DER certificate ({exc})"
                          ) from None
    return cert.public_bytes(Encoding.DER)


def _check_key(path: Path) -> None:
    from cryptography.hazmat.primitives.serialization import (
        load_der_private_key,
        load_pem_private_key,
    )

    try:
        data = path.read_bytes()
        (load_pem_private_key if b"-----BEGIN" in data else load_der_private_key)(data, None)
    except (OSError, ValueError, TypeError) as exc:
        raise ConfigError(f"OPC UA --key {path}: not a readable unencrypted PEM or DER private "
                          f"key ({exc})") from None


def settings_of(args: argparse.Namespace) -> OpcUaSettings:
    """The checked settings; a one-line ConfigError for anything wrong or unsafe."""
    from monitor.adapters.opcua_users import load_users

    url = urlparse(args.endpoint)
    try:
        port = url.port
    except ValueError:
        port = None
    if url.scheme != "opc.tcp" or not url.hostname or not port:
        raise ConfigError(f"monitor bridge opcua: --endpoint {args.endpoint!r}: expected "
                          "opc.tcp://HOST:PORT[/path]")
    if (args.cert is None) != (args.key is None):
        raise ConfigError("monitor bridge opcua: give both --cert and --key, or neither")
    secure = args.cert is not None
    if not secure:
        if not _loopback(url.hostname):
            raise ConfigError(f"monitor bridge opcua: refusing to serve {url.hostname} without "
                              "security: give --cert and --key (Basic256Sha256), or listen on "
                              "127.0.0.1")
        for flag, value in (("--users", args.users), ("--client-certs", args.client_certs)):
            if value is not None:
                raise ConfigError(f"monitor bridge opcua: {flag} needs --cert and --key (a "
                                  "password over NoSecurity travels in clear text)")
    if args.no_anonymous and args.users is None:
        raise ConfigError("monitor bridge opcua: --no-anonymous needs --users (else nobody "
                          "could connect)")
    if args.max_clients < 1:
        raise ConfigError("monitor bridge opcua: --max-clients must be at least 1")
    if not 0.1 <= args.handshake_s <= 60:
        raise ConfigError("monitor bridge opcua: --handshake-s must be in [0.1, 60] s")
    if not args.stale_ms >= 2 * args.tick * 1000.0:
        raise ConfigError(f"monitor bridge opcua: --stale-ms {args.stale_ms:g} must be at "
                          f"least two ticks ({2 * args.tick * 1000.0:g} ms)")
    if secure:
        _load_der(args.cert, "OPC UA --cert")
        _check_key(args.key)
    trusted = None
    if args.client_certs is not None:
        if not args.client_certs.is_dir():
            raise ConfigError(f"monitor bridge opcua: --client-certs {args.client_certs}: "
                              "not a directory")
        trusted = tuple(_load_der(f, "OPC UA client certificate")
                        for f in sorted(args.client_certs.iterdir())
                        if f.suffix.lower() in (".der", ".pem", ".crt"))
        if not trusted:
            raise ConfigError(f"monitor bridge opcua: --client-certs {args.client_certs}: no "
                              ".der/.pem/.crt certificate in it")
    users = load_users(args.users) if args.users is not None else {}
    return OpcUaSettings(endpoint=args.endpoint, cert=args.cert, key=args.key, users=users,
                         anonymous=not args.no_anonymous, client_certs=trusted,
                         max_clients=args.max_clients, stale_ms=args.stale_ms,
                         handshake_s=args.handshake_s)


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_arguments(args: argparse.Namespace) -> None:
    """Called by `monitor bridge` before Zenoh opens: bad options fail at once."""
    settings_of(args)


def make_outputs(args: argparse.Namespace, session, keys) -> list[Output]:
    out = OpcUaOutput(settings_of(args), camera_ids=tuple(args.cameras))
    out.start()
    return [out]


# --- the server ---------------------------------------------------------------------------------


class OpcUaOutput:
    """An OPC UA server showing the newest snapshot (see the module doc)."""

    name = "opcua"

    def __init__(self, settings: OpcUaSettings, camera_ids: tuple[str, ...] = ()) -> None:
        self.settings = settings
        self.camera_ids = camera_ids
        self._latest: SafetySnapshot | None = None
        self._pending = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake: asyncio.Event | None = None
        self._closing: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="opcua-server", daemon=True)
        self.namespace_index: int | None = None
        self.stale_stops = 0  # times the server wrote STOP because no snapshot came

    # --- the follower's side (never blocks) ---

    def publish(self, snapshot: SafetySnapshot) -> None:
        self._latest = snapshot
        loop = self._loop
        if loop is not None and not self._pending:
            self._pending = True
            loop.call_soon_threadsafe(self._wake_up)

    def start(self, timeout: float = 30.0) -> None:
        self._thread.start()
        if not self._ready.wait(timeout):
            raise ConfigError(f"monitor bridge opcua: the OPC UA server did not start within "
                              f"{timeout:g} s")
        if self._error is not None:
            raise ConfigError(f"monitor bridge opcua: cannot serve {self.settings.endpoint}: "
                              f"{self._error}")

    def close(self) -> None:
        loop, closing = self._loop, self._closing
        if loop is not None and closing is not None and self._thread.is_alive():
            with contextlib.suppress(RuntimeError):  # the loop is already gone
                loop.call_soon_threadsafe(closing.set)
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    # --- the server's thread ---

    def _wake_up(self) -> None:
        if self._wake is not None:
            self._wake.set()

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # reported by start(); after that, logged
            if not self._ready.is_set():
                self._error = exc
                self._ready.set()
            else:
                log.error("OPC UA server stopped: %s", exc)

    async def _main(self) -> None:
        from asyncua import ua

        self._wake, self._closing = asyncio.Event(), asyncio.Event()
        server, nodes = await self._build()
        try:
            await server.start()
        except OSError as exc:
            raise ConfigError(str(exc).split("\n")[0]) from None
        shown = initial_values(self.camera_ids)
        stale_s = self.settings.stale_ms / 1000.0
        last_counter: int | None = None
        self._loop = asyncio.get_running_loop()
        self._ready.set()
        try:
            while not self._closing.is_set():
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), timeout=stale_s / 4)
                self._wake.clear()
                self._pending = False
                snap = self._latest
                now = time.monotonic()
                new = next_values(snap, now, stale_s, shown, last_counter, self.camera_ids)
                if new is None or snap is None:
                    continue
                if new["ReasonCode"] == "adapter_stale":
                    self.stale_stops += 1
                    log.error("OPC UA: no snapshot for %.0f ms: showing STOP",
                              (now - snap.mono) * 1000)
                else:
                    last_counter = snap.counter
                shown = await self._write(server, nodes, shown, new, ua, snap)
        finally:
            self._loop = None
            await _shutdown(server)

    async def _write(self, server, nodes: dict, shown: dict, new: dict, ua,
                     snap: SafetySnapshot | None) -> dict:
        source = new["SnapshotTime"] if snap is not None else datetime.now(UTC)
        written = dict(shown)
        try:
            for name in write_order(shown, new):
                var, vtype = nodes[name]
                dv = ua.DataValue(ua.Variant(new[name], vtype), SourceTimestamp=source,
                                  ServerTimestamp=datetime.now(UTC))
                await server.write_attribute_value(var, dv)
                written[name] = new[name]
        except Exception as exc:  # never leave a RUN standing beside a failed update
            log.error("OPC UA: writing the variables failed (%s): showing STOP", exc)
            for name in STATE_VARS:
                var, vtype = nodes[name]
                value = {"State": 0, "StateName": "STOP", "SpeedScale": 0.0}.get(name, True)
                await server.write_attribute_value(var, ua.DataValue(ua.Variant(value, vtype)))
                written[name] = value
        return written

    async def _build(self):
        from asyncua import ua

        from monitor.adapters.opcua_guard import GuardedServer

        # a refused request is answered with its status code; logging each one at ERROR would
        # let any client flood our log with writes
        logging.getLogger("asyncua.server.uaprocessor").setLevel(logging.CRITICAL)
        s = self.settings
        server = GuardedServer(user_manager=_Users(s.users, s.anonymous),
                               handshake_s=s.handshake_s)
        await init_without_collections(server)
        server.set_endpoint(s.endpoint)
        server.set_server_name("workcell-monitor safety status (non-safety)")
        await server.set_application_uri(APPLICATION_URI)
        server.product_uri = "urn:workcell-monitor"
        server.manufacturer_name = "workcell-monitor"
        rules = _ReadOnly()
        if s.secure:
            await server.load_certificate(str(s.cert))
            await server.load_private_key(str(s.key))
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
                                       permission_ruleset=rules)
        else:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity],
                                       permission_ruleset=rules)
        tokens: list[type] = []
        if s.anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        if s.users:
            tokens.append(ua.UserNameIdentityToken)
        server.set_identity_tokens(tokens)
        server.iserver.max_connections = s.max_clients
        if s.client_certs is not None:
            server.set_certificate_validator(_trust_only(s.client_certs))
        idx = await server.register_namespace(NAMESPACE)
        self.namespace_index = idx
        root = await server.nodes.objects.add_object(
            ua.NodeId(OBJECT, idx), ua.QualifiedName(OBJECT, idx))
        ssm = await root.add_object(ua.NodeId(node_id(SSM), idx), ua.QualifiedName(SSM, idx))
        values = initial_values(self.camera_ids)
        nodes: dict[str, tuple[Any, Any]] = {}
        for v in VARIABLES:
            parent, leaf = (ssm, v.name.split(".", 1)[1]) if v.name.startswith(SSM) else (
                root, v.name)
            vtype = getattr(ua.VariantType, v.vtype)
            var = await parent.add_variable(
                ua.NodeId(node_id(v.name), idx), ua.QualifiedName(leaf, idx),
                ua.Variant(values[v.name], vtype, is_array=v.array or None), datatype=None)
            if v.array:
                await var.write_value_rank(ua.ValueRank.OneDimension)
            await var.write_attribute(ua.AttributeIds.Description, ua.DataValue(
                ua.Variant(ua.LocalizedText(v.description), ua.VariantType.LocalizedText)))
            nodes[v.name] = (var.nodeid, vtype)
        return server, nodes


async def init_without_collections(server) -> None:
    """``server.init()`` with the cyclic garbage collector paused, then its objects frozen.

    The standard address space is about half a million Python objects that live as long as the
    server. Built with the collector running, it costs 3.2 s of CPU on a 2-core EPYC (the
    collector scans the growing heap again and again), paused 1.9 s. Left in the collector's
    generations, every later full collection scans them again: a 0.3-0.5 s pause of the server's
    thread, longer than the 250 ms stale limit, at a moment nobody chose. ``gc.freeze`` moves
    them (and whatever else lives by then) out of all future collections.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        await server.init()
    finally:
        gc.freeze()
        if was_enabled:
            gc.enable()


async def _shutdown(server) -> None:
    """Stop ``server`` within the adapter's shutdown grace: asyncua's clock task sleeps 1 s
    between updates and ``stop`` waits for it, so cancel it first."""
    task = getattr(server.iserver, "time_task", None)
    if task is not None:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        server.iserver.time_task = None
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(server.stop(), 0.8)


class _Users:
    """asyncua user manager: anonymous (when allowed) and the users file; nobody is admin."""

    def __init__(self, users: dict, anonymous: bool) -> None:
        self.users, self.anonymous = users, anonymous

    def get_user(self, iserver, username=None, password=None, certificate=None):
        from asyncua.crypto.permission_rules import User, UserRole

        if username is None:  # no X509 user tokens are offered: the anonymous token
            return User(role=UserRole.Anonymous) if self.anonymous else None
        h = self.users.get(username) if isinstance(username, str) else None
        if h is None or not isinstance(password, str) or not h.matches(password):
            log.warning("OPC UA: login refused for user %r", username)
            return None
        return User(role=UserRole.User, name=username)


class _ReadOnly:
    """Every user may read, browse and subscribe; nobody may write, call or change nodes."""

    def __init__(self) -> None:
        from asyncua import ua
        from asyncua.crypto.permission_rules import USER_TYPES

        refused = {ua.ObjectIds.WriteRequest_Encoding_DefaultBinary,
                   ua.ObjectIds.CallRequest_Encoding_DefaultBinary}
        self.allowed = {ua.NodeId(t) for t in USER_TYPES if t not in refused}

    def check_validity(self, user, action_type_id, body) -> bool:
        return action_type_id in self.allowed


def _trust_only(trusted: tuple[bytes, ...]):
    async def validate(certificate, app_description) -> None:
        from asyncua import ua
        from asyncua.common.utils import ServiceError
        from cryptography.hazmat.primitives.serialization import Encoding

        if certificate.public_bytes(Encoding.DER) not in trusted:
            log.warning("OPC UA: untrusted client certificate from %s",
                        getattr(app_description, "ApplicationUri", "?"))
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)

    return validate
