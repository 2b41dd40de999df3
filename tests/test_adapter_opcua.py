"""`monitor bridge opcua` (monitor/adapters/opcua.py, docs/opcua.md): a real asyncua server in
the adapter process, a real signed monitor on 127.0.0.1 and a real asyncua client.

Fails towards STOP: before any command, the monitor killed or frozen, a forged RUN, the
adapter's own loop stuck; nobody can write; the secure endpoint takes Basic256Sha256 and
users."""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import gc
import math
import multiprocessing
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

asyncua = pytest.importorskip("asyncua")
from asyncua import ua  # noqa: E402

from monitor.adapters.opcua import (  # noqa: E402
    APPLICATION_URI,
    NAMESPACE,
    VARIABLES,
    OpcUaOutput,
    OpcUaSettings,
    init_without_collections,
    initial_values,
    node_id,
    values_of,
    write_order,
)
from monitor.adapters.opcua_users import user_line  # noqa: E402
from monitor.adapters.snapshot import snapshot_of  # noqa: E402
from monitor.bus.session import BusConfig, SafetyBus  # noqa: E402
from monitor.policy import Command, Reason  # noqa: E402
from monitor.wire.consumer import Verdict  # noqa: E402
from monitor.wire.signing import new_key_pair  # noqa: E402
from tests.helpers import assert_one_line_error, free_port, run_monitor, wait_for  # noqa: E402
from tests.opcua_kit import ConnectedClient as Client  # noqa: E402
from tests.opcua_kit import connected as _connected  # noqa: E402

TTL_MS = 300
BUDGET_S = (TTL_MS + 100) / 1000.0  # STOP within ttl + 100 ms of the monitor going away


# --- helpers ----------------------------------------------------------------------------------


class Adapter:
    """`python -m monitor bridge opcua ...` in its own process, following cell ``cell``."""

    def __init__(self, zport: int, cell: str, pub: Path, *extra: str,
                 endpoint: str | None = None) -> None:
        self.port = free_port()
        self.url = endpoint or f"opc.tcp://127.0.0.1:{self.port}/wm"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "monitor", "bridge", "opcua", "--cell", cell,
             "--connect", f"tcp/127.0.0.1:{zport}", "--monitor-key", str(pub),
             "--ttl-ms", str(TTL_MS), "--endpoint", self.url, *extra],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.stderr: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()
        assert wait_for(lambda: any("following" in line for line in self.stderr)
                        or self.proc.poll() is not None, 60), "adapter did not start"
        assert self.proc.poll() is None, "".join(self.stderr)

    def _read(self) -> None:
        for line in self.proc.stderr:
            self.stderr.append(line)

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


class Reader:
    """An asyncua client with the variables by name."""

    def __init__(self, client: Client) -> None:
        self.client = client
        idx = client.get_namespace_index(NAMESPACE)
        self.nodes = {v.name: client.get_node(f"ns={idx};s={node_id(v.name)}")
                      for v in VARIABLES}

    def __getitem__(self, name: str):
        return self.nodes[name].read_value()

    def state(self) -> int:
        return self.nodes["State"].read_value()


def connect(url: str, **kw) -> Client:
    client = Client(url, timeout=10)
    for k, v in kw.items():
        getattr(client, f"set_{k}")(v)
    return _connected(client)


class Pipeline:
    """Hands ``bus`` the current command every 50 ms, like the monitor's pipeline."""

    def __init__(self, bus: SafetyBus) -> None:
        self.bus = bus
        self.command = Command("STOP", 0.0, (Reason("startup", "test starting"),))
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.wait(0.05):
            self.bus.publish_command(self.command)

    def set(self, command: Command) -> None:
        self.command = command
        self.bus.publish_command(command)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=5)


@pytest.fixture()
def keys(tmp_path):
    private, public, _ = new_key_pair(tmp_path / "monitor.key")
    return private, public


def _monitor_main(port: int, cell: str, key: str) -> None:
    """A monitor process: signed RUN every 50 ms until killed."""
    from monitor.bus.session import BusConfig, SafetyBus
    from monitor.policy import Command

    cfg = BusConfig(cell=cell, instance="mon-op", listen=(f"tcp/127.0.0.1:{port}",),
                    heartbeat_hz=20.0, ttl_ms=TTL_MS, signing_key=key)
    with SafetyBus(cfg) as bus:
        while True:
            bus.publish_command(Command("RUN", 1.0))
            time.sleep(0.05)


# --- pure parts --------------------------------------------------------------------------------


def _snap(state: str, scale: float, code: str = "", counter: int = 1, cams=("cam0",)):
    reasons = [] if not code else [{"code": code, "message": "m", "zone_id": "P"}]
    cmd = {"state": state, "speed_scale": scale, "reasons": reasons}
    return snapshot_of(Verdict(state, scale, "", 3, cmd), 10.0, 1e9, counter, 9.99, cams)


def test_the_state_is_written_first_when_safer_and_last_when_less_safe():
    run = values_of(_snap("RUN", 1.0), ("cam0",))
    stop = values_of(_snap("STOP", 0.0, "protective_zone", 2), ("cam0",))
    down, up = write_order(run, stop), write_order(stop, run)
    assert down[0] == "State" and "ReasonCode" in down[4:]
    assert up[-4:] and "State" in up[-4:] and up.index("State") > up.index("ReasonCode")
    assert initial_values(("cam0",))["State"] == 0  # before the first snapshot: STOP
    assert initial_values(("cam0",))["CamerasOk"] == [False]
    assert stop["SafetyStateManagement.VisionSafetyTriggered"] is True
    assert run["SafetyStateManagement.VisionSafetyTriggered"] is False


@pytest.mark.parametrize("collecting", [True, False])
def test_the_address_space_is_built_without_collections_and_kept_out_of_later_ones(collecting):
    """asyncua's standard address space (~480k objects) is built with the collector paused
    and then frozen, so no later full collection pauses the server's thread to scan it; the
    collector's own setting is left as it was."""
    was = gc.isenabled()
    (gc.enable if collecting else gc.disable)()
    try:
        before = gc.get_freeze_count()
        seen: list[bool] = []

        class Probe(asyncua.Server):
            async def init(self, shelf_file=None) -> None:
                seen.append(gc.isenabled())
                await super().init(shelf_file)

        asyncio.run(init_without_collections(Probe()))
        assert seen == [False]
        assert gc.get_freeze_count() - before > 100_000
        assert gc.isenabled() is collecting
    finally:
        (gc.enable if was else gc.disable)()


def test_the_server_shows_stop_itself_when_the_adapter_loop_stops_handing_over():
    """The follower stuck (not the process): no snapshot for --stale-ms -> STOP, with the
    heartbeat and the snapshot time frozen for a client to see."""
    port = free_port()
    out = OpcUaOutput(OpcUaSettings(endpoint=f"opc.tcp://127.0.0.1:{port}/wm",
                                    stale_ms=200.0), camera_ids=("cam0",))
    out.start()
    try:
        with connect(out.settings.endpoint) as client:
            r = Reader(client)
            assert r.state() == 0 and r["ReasonCode"] == "no_command"  # before any snapshot
            cmd = {"state": "RUN", "speed_scale": 1.0, "reasons": []}
            for i in range(1, 6):
                now = time.monotonic()
                out.publish(snapshot_of(Verdict("RUN", 1.0, "", i, cmd), now, time.time(), i,
                                        now - 0.01, ("cam0",)))
                time.sleep(0.02)
            assert wait_for(lambda: r["Heartbeat"] == 5)
            assert r.state() == 2 and r["CamerasOk"] == [True]
            t_last = time.monotonic()
            assert wait_for(lambda: r.state() == 0)  # nothing more handed over
            assert time.monotonic() - t_last < 2.0
            assert r["ReasonCode"] == "adapter_stale" and r["Heartbeat"] == 5
            assert r["CamerasOk"] == [False] and out.stale_stops == 1
    finally:
        out.close()


# --- the adapter process --------------------------------------------------------------------


@pytest.mark.slow
def test_a_client_reads_run_slow_stop_of_a_signed_monitor_and_the_heartbeat(keys):
    private, public = keys
    zport, cell = free_port(), "op1"
    # the adapter starts first: nothing on the bus yet -> STOP, and its heartbeat moves
    adapter = Adapter(zport, cell, public, "--camera", "cam0")
    try:
        with connect(adapter.url) as client:
            r = Reader(client)
            assert r.state() == 0 and r["ReasonCode"] == "no_command"
            beat = r["Heartbeat"]
            assert wait_for(lambda: r["Heartbeat"] != beat)
            cfg = BusConfig(cell=cell, instance="mon-op", listen=(f"tcp/127.0.0.1:{zport}",),
                            heartbeat_hz=20.0, ttl_ms=TTL_MS, signing_key=str(private))
            with SafetyBus(cfg) as bus:
                pipe = Pipeline(bus)
                try:
                    pipe.set(Command("RUN", 1.0))
                    assert wait_for(lambda: r.state() == 2, what=lambda: r["Reason"])
                    assert r["StateName"] == "RUN" and r["SpeedScale"] == 1.0
                    assert r["CameraOk"] and r["CamerasOk"] == [True]
                    assert r["MonitorInstance"] == "mon-op" and r["Seq"] > 0
                    assert not r["SafetyStateManagement.VisionSafetyTriggered"]
                    assert 0.0 <= r["CommandAgeMs"] < 5000
                    pipe.set(Command("SLOW", 0.4, (Reason("warning_zone", "person 1 in W",
                                                          zone_id="W"),)))
                    assert wait_for(lambda: r.state() == 1)
                    assert r["SpeedScale"] == pytest.approx(0.4) and r["ZoneId"] == "W"
                    assert r["ReasonCode"] == "warning_zone"
                    pipe.set(Command("STOP", 0.0, (Reason("protective_zone", "person 1 in P",
                                                          zone_id="P"),), latched=True))
                    assert wait_for(lambda: r.state() == 0)
                    assert r["ReasonCode"] == "protective_zone" and r["Latched"]
                    assert r["SafetyStateManagement.VisionSafetyTriggered"]
                    assert "protective_zone" in r["SafetyStateManagement.VisionSafetyInformation"]
                    beat = r["Heartbeat"]
                    assert wait_for(lambda: r["Heartbeat"] > beat)  # the adapter's heartbeat moves
                    stamp = r.nodes["Heartbeat"].read_data_value()
                    assert abs(stamp.SourceTimestamp.timestamp() - time.time()) < 5.0
                finally:
                    pipe.close()
    finally:
        assert adapter.stop() == 0, "".join(adapter.stderr)


def _forge(cell: str, zport: int, stop: threading.Event, tmp_path: Path) -> None:
    """Unsigned RUN, and RUN signed by a key nobody pinned, with seqs far ahead."""
    import json

    from monitor.bus.session import BusKeys, open_session
    from monitor.wire.consumer import COMMAND_SCHEMA
    from monitor.wire.signing import load_private_key

    forger = load_private_key(new_key_pair(tmp_path / "forger.key")[0])
    key = BusKeys.of(f"workcell/{cell}/").command
    with open_session(BusConfig(cell=cell, instance="forger",
                                connect=(f"tcp/127.0.0.1:{zport}",))) as s:
        seq = 10**6
        while not stop.wait(0.01):
            seq += 1
            body = {"schema": COMMAND_SCHEMA, "cell": cell, "instance": "mon-op",
                    "boot": "forged", "seq": seq, "state": "RUN", "speed_scale": 1.0,
                    "ttl_ms": 1000, "wall": time.time(), "reasons": []}
            payload = json.dumps(body).encode()
            s.put(key, payload)
            s.put(key, payload, attachment=forger.sign(key, payload))


@pytest.mark.slow
@pytest.mark.parametrize("how", ["kill", "sigstop", "kill+forged-run"])
def test_stop_within_ttl_plus_100ms_when_the_monitor_goes_away(keys, tmp_path, how):
    private, public = keys
    zport, cell = free_port(), "op2"
    mon = multiprocessing.get_context("spawn").Process(
        target=_monitor_main, args=(zport, cell, str(private)), daemon=True)
    mon.start()
    adapter = Adapter(zport, cell, public)
    stop_forger = threading.Event()
    try:
        with connect(adapter.url) as client:
            r = Reader(client)
            assert wait_for(lambda: r.state() == 2, what=lambda: r["Reason"])
            state_node = r.nodes["State"]
            forger = None
            if how.endswith("forged-run"):
                forger = threading.Thread(target=_forge, args=(cell, zport, stop_forger,
                                                               tmp_path), daemon=True)
                forger.start()
                time.sleep(0.3)
                assert r.state() == 2  # the real monitor still speaks
            t_gone = time.time()
            os.kill(mon.pid, signal.SIGSTOP if how == "sigstop" else signal.SIGKILL)
            reads: list[tuple[float, int]] = []

            def stopped() -> bool:
                reads.append((time.time(), r.state()))
                return reads[-1][1] == 0

            assert wait_for(stopped, what=lambda: reads[-3:])
            dv = state_node.read_data_value()
            assert dv.Value.Value == 0
            # the adapter's own time of the STOP (its snapshot clock, same host)
            took = dv.SourceTimestamp.timestamp() - t_gone
            assert took <= BUDGET_S, f"STOP {took * 1000:.0f} ms after the monitor went away"
            end = time.monotonic() + 1.0
            while time.monotonic() < end:  # and it stays STOP (forged RUN or not)
                reads.append((time.time(), r.state()))
            assert all(s == 0 for t, s in reads if t > t_gone + BUDGET_S + 0.05), reads
            assert r["ReasonCode"] in ("ttl", "liveliness")
            stop_forger.set()
            if forger is not None:
                forger.join(timeout=5)
    finally:
        stop_forger.set()
        if how == "sigstop":
            os.kill(mon.pid, signal.SIGCONT)
        mon.kill()
        mon.join(timeout=5)
        code = adapter.stop()
        # after a forged flood the adapter's main thread sometimes misses SIGINT inside the
        # inbox wait (shared follower; open, see docs/opcua.md): StopSignals' forced exit (130
        # after 1.5 s) is the designed backstop, and the OPC UA output showed STOP meanwhile
        assert code == 0 or (how.endswith("forged-run") and code == 130), "".join(
            adapter.stderr)


# --- bad input ---------------------------------------------------------------------------------


REFUSED = (ua.StatusCodes.BadUserAccessDenied, ua.StatusCodes.BadNotWritable)


def _refused(call) -> int:
    """The OPC UA status code of a refused request (fails if it was accepted)."""
    try:
        call()
    except ua.UaStatusCodeError as exc:
        return exc.code
    raise AssertionError("the server accepted it")


@pytest.mark.slow
def test_writes_garbage_and_a_read_flood_get_status_errors_never_run(keys):
    private, public = keys
    zport, cell = free_port(), "op3"
    cfg = BusConfig(cell=cell, instance="mon-op", listen=(f"tcp/127.0.0.1:{zport}",),
                    heartbeat_hz=20.0, ttl_ms=TTL_MS, signing_key=str(private))
    with SafetyBus(cfg) as bus:
        pipe = Pipeline(bus)
        pipe.set(Command("STOP", 0.0, (Reason("protective_zone", "person 1 in P",
                                              zone_id="P"),)))
        adapter = Adapter(zport, cell, public, "--max-clients", "8")
        try:
            with connect(adapter.url) as client:
                r = Reader(client)
                assert wait_for(lambda: r["ReasonCode"] == "protective_zone", 20.0)
                states = [r.state()]
                # 1. every variable, written with its own type and with garbage
                for v in VARIABLES:
                    node = r.nodes[v.name]
                    vt = getattr(ua.VariantType, v.vtype)
                    good = ua.Variant(node.read_value(), vt)
                    for value in (good, ua.Variant(2, ua.VariantType.Int32),
                                  ua.Variant("RUN", ua.VariantType.String),
                                  ua.Variant(float("nan"), ua.VariantType.Double),
                                  ua.Variant(b"\x00" * 70000, ua.VariantType.ByteString)):
                        assert _refused(lambda n=node, x=value: n.write_value(x)) in REFUSED
                    states.append(r.state())
                state = r.nodes["State"]
                for value in (2, 7, -1, 2**31 - 1):  # RUN and out of range
                    assert _refused(lambda x=value: state.write_value(
                        ua.Variant(x, ua.VariantType.Int32))) in REFUSED
                for attr in (ua.AttributeIds.AccessLevel, ua.AttributeIds.UserAccessLevel):
                    assert _refused(lambda a=attr: state.write_attribute(a, ua.DataValue(
                        ua.Variant(3, ua.VariantType.Byte)))) in REFUSED
                assert _refused(lambda: state.write_attribute(
                    ua.AttributeIds.DisplayName, ua.DataValue(ua.Variant(
                        ua.LocalizedText("x"), ua.VariantType.LocalizedText)))) in REFUSED
                objects = client.nodes.objects
                assert _refused(lambda: objects.add_variable(
                    2, "Injected", 2)) in REFUSED  # AddNodes
                assert _refused(lambda: client.delete_nodes([state])) in REFUSED
                assert _refused(lambda: client.nodes.server.call_method(
                    "0:GetMonitoredItems", ua.Variant(1, ua.VariantType.UInt32))) in REFUSED
                # 2. raw garbage on the TCP port
                host, port = "127.0.0.1", int(adapter.url.split(":")[2].split("/")[0])
                for junk in (os.urandom(4096), b"HELF" + b"\xff" * 60,
                             b"HELF\x20\x00\x00\x00" + os.urandom(28), b"MSGF" + os.urandom(64)):
                    with socket.create_connection((host, port), timeout=5) as s:
                        s.sendall(junk)
                        s.settimeout(0.5)  # the server answers an error or closes at once
                        with contextlib.suppress(OSError):
                            s.recv(1024)
                # 3. a flood of reads from 4 clients, and more clients than allowed
                bad: list[int] = []
                connected = threading.Semaphore(0)
                done: list[int] = []

                def flood() -> None:
                    with connect(adapter.url) as c:
                        node = Reader(c).nodes["State"]
                        connected.release()  # the extra clients come after the flooders
                        for _ in range(60):
                            value = node.read_value()
                            if value != 0:
                                bad.append(value)
                        done.append(1)

                threads = [threading.Thread(target=flood) for _ in range(4)]
                for t in threads:
                    t.start()
                for _ in threads:
                    assert connected.acquire(timeout=60), "a flooding client did not connect"
                extra = []
                for _ in range(8):  # above --max-clients 8 with the others
                    with contextlib.suppress(Exception):
                        extra.append(connect(adapter.url))
                for t in threads:
                    t.join(timeout=120)
                for c in extra:
                    c.disconnect()
                assert not bad and len(done) == 4 and len(extra) < 8
                states.append(r.state())
                # still serving, still beating, still STOP, never RUN
                beat = r["Heartbeat"]
                assert wait_for(lambda: r["Heartbeat"] != beat)
                assert set(states) == {0} and r["ReasonCode"] == "protective_zone"
                assert adapter.proc.poll() is None
        finally:
            pipe.close()
            assert adapter.stop() == 0, "".join(adapter.stderr)


# --- security ----------------------------------------------------------------------------------


def _cert(tmp_path: Path, name: str, uri: str) -> tuple[Path, Path]:
    """A self-signed RSA-2048 certificate (DER) and key (PEM) for an OPC UA application."""
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = dt.datetime.now(dt.UTC)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(days=1))
            .not_valid_after(now + dt.timedelta(days=30))
            .add_extension(x509.SubjectAlternativeName([
                x509.UniformResourceIdentifier(uri), x509.DNSName("localhost"),
                x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(
                digital_signature=True, content_commitment=True, key_encipherment=True,
                data_encipherment=True, key_agreement=False, key_cert_sign=False,
                crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .sign(key, hashes.SHA256()))
    cert_path, key_path = tmp_path / f"{name}.der", tmp_path / f"{name}.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                           serialization.PrivateFormat.TraditionalOpenSSL,
                                           serialization.NoEncryption()))
    return cert_path, key_path


def _secure(url: str, cert: Path, key: Path, user: str | None = None,
            password: str | None = None) -> Client:
    client = Client(url, timeout=10)
    client.application_uri = "urn:workcell-monitor:test-client"
    client.set_security_string(f"Basic256Sha256,SignAndEncrypt,{cert},{key}")
    if user is not None:
        client.set_user(user)
        client.set_password(password)
    return _connected(client)


@pytest.mark.slow
def test_secure_endpoint_basic256sha256_with_users_and_read_only_anonymous(keys, tmp_path):
    _, public = keys
    server_cert, server_key = _cert(tmp_path, "server", APPLICATION_URI)
    client_cert, client_key = _cert(tmp_path, "client", "urn:workcell-monitor:test-client")
    users = tmp_path / "users.txt"
    users.write_text("# OPC UA users\n" + user_line("anna", "s3cret pw", iterations=2000)
                     + "\n")
    adapter = Adapter(free_port(), "op4", public, "--cert", str(server_cert), "--key",
                      str(server_key), "--users", str(users))
    try:
        with _secure(adapter.url, client_cert, client_key, "anna", "s3cret pw") as c:
            r = Reader(c)
            assert r.state() == 0 and r["ReasonCode"] == "no_command"
            assert c.aio_obj.security_policy.URI.endswith("#Basic256Sha256")
            assert _refused(lambda: r.nodes["State"].write_value(
                ua.Variant(2, ua.VariantType.Int32))) in REFUSED
        with _secure(adapter.url, client_cert, client_key) as c:  # anonymous, encrypted
            r = Reader(c)
            assert r.state() == 0
            assert _refused(lambda: r.nodes["State"].write_value(
                ua.Variant(2, ua.VariantType.Int32))) in REFUSED
        with pytest.raises(ua.UaStatusCodeError) as wrong:
            _secure(adapter.url, client_cert, client_key, "anna", "guess")
        assert wrong.value.code == ua.StatusCodes.BadUserAccessDenied
        with pytest.raises(Exception):  # noqa: B017 - no NoSecurity endpoint at all
            connect(adapter.url).disconnect()
        assert adapter.proc.poll() is None
    finally:
        assert adapter.stop() == 0, "".join(adapter.stderr)


@pytest.mark.parametrize("extra, needle", [
    (["--endpoint", "opc.tcp://0.0.0.0:4840"], "refusing to serve 0.0.0.0 without security"),
    (["--endpoint", "opc.tcp://10.1.2.3:4840"], "refusing to serve 10.1.2.3"),
    (["--users", "users.txt"], "--users needs --cert and --key"),
    (["--endpoint", "http://127.0.0.1:80"], "expected opc.tcp://HOST:PORT"),
    (["--cert", "missing.der"], "give both --cert and --key"),
    (["--cert", "missing.der", "--key", "missing.pem"], "--cert missing.der"),
    (["--no-anonymous"], "--no-anonymous needs --users"),
    (["--stale-ms", "10"], "--stale-ms 10 must be at least two ticks"),
], ids=["any-address", "lan-address", "users-in-clear", "scheme", "half-cert", "no-cert-file",
        "nobody-could-connect", "stale-below-tick"])
def test_bad_or_unsafe_options_are_one_line_errors(tmp_path, extra, needle):
    proc = run_monitor("bridge", "opcua", "--unauthenticated", "--connect",
                       f"tcp/127.0.0.1:{free_port()}", *extra, timeout=60, cwd=tmp_path)
    assert_one_line_error(proc, needle)


def test_a_malformed_users_file_is_a_one_line_error(tmp_path):
    from monitor.adapters.opcua_users import load_users
    from monitor.errors import ConfigError
    from tests.helpers import assert_one_line

    bad = tmp_path / "users.txt"
    for text, needle in (("anna:secret\n", "line 1: expected NAME:pbkdf2-sha256"),
                         ("anna:pbkdf2-sha256:x:00:00\n", "ITERATIONS must be an integer"),
                         ("# nobody\n", "no users in it"),
                         (user_line("a", "p", 1000) + "\n" + user_line("a", "q", 1000),
                          "line 2: user a appears twice")):
        bad.write_text(text)
        with pytest.raises(ConfigError) as err:
            load_users(bad)
        assert_one_line(err.value, needle)
    good = user_line("anna", "pw", 1000)
    bad.write_text(good)
    h = load_users(bad)["anna"]
    assert h.matches("pw") and not h.matches("pw ") and not math.isnan(h.iterations)
