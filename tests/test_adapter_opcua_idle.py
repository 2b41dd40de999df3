"""Idle and half-open TCP connections on the OPC UA port never lock a real client out
(monitor/adapters/opcua_guard.py): a real asyncua server in this process, raw sockets that
send nothing, real asyncua clients."""

from __future__ import annotations

import socket
import time

import pytest

pytest.importorskip("asyncua")

from monitor.adapters.opcua import NAMESPACE, OpcUaOutput, OpcUaSettings, node_id
from monitor.adapters.opcua_guard import DEAD_PEER_S, KEEPALIVE, keep_alive
from tests.helpers import free_port
from tests.opcua_kit import ConnectedClient as Client
from tests.opcua_kit import connected as connect_once

WAIT_S = 20.0  # generous: a loaded 2-core machine


def server(**settings) -> OpcUaOutput:
    port = free_port()
    out = OpcUaOutput(OpcUaSettings(endpoint=f"opc.tcp://127.0.0.1:{port}/wm", **settings))
    out.start()
    return out


def port_of(out: OpcUaOutput) -> int:
    return int(out.settings.endpoint.split(":")[2].split("/")[0])


def read_state(client: Client) -> int:
    idx = client.get_namespace_index(NAMESPACE)
    return client.get_node(f"ns={idx};s={node_id('State')}").read_value()


def connected(url: str) -> Client:
    return connect_once(Client(url, timeout=WAIT_S))


def closed_by_server(sock: socket.socket, timeout: float = WAIT_S) -> bool:
    """The server closed ``sock`` (EOF or reset) within ``timeout``."""
    sock.settimeout(timeout)
    try:
        return sock.recv(1024) == b""
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False


def test_sixteen_idle_sockets_never_lock_a_real_client_out():
    """The issue: 16 idle sockets (the default --max-clients) held every client out. The
    handshake limit is set far beyond the wait here, so only a freed slot can let the client
    in: an idle connection gives its slot to the real client, an activated one never does."""
    out = server(max_clients=16, handshake_s=60.0)
    idle: list[socket.socket] = []
    try:
        first = connected(out.settings.endpoint)  # an activated session from before
        try:
            assert read_state(first) == 0
            idle = [socket.create_connection(("127.0.0.1", port_of(out)), timeout=5)
                    for _ in range(16)]
            # 1 + 16 > 16: the last idle socket took the slot of the oldest idle one, so the
            # server has seen all of them
            assert closed_by_server(idle[0]), "no idle connection gave its slot up"
            start = time.monotonic()
            with connected(out.settings.endpoint) as client:
                assert read_state(client) == 0  # STOP before any command: a real read
                took = time.monotonic() - start
            print(f"\nconnect + read with 16 idle sockets held: {took * 1000:.0f} ms "
                  "(required: under 2 s)")
            assert read_state(first) == 0  # the activated session kept its slot
        finally:
            first.disconnect()
    finally:
        for s in idle:
            s.close()
        out.close()


def test_idle_and_half_sent_connections_are_closed_after_the_handshake_time():
    out = server(handshake_s=0.5)
    try:
        port = port_of(out)
        with socket.create_connection(("127.0.0.1", port), timeout=5) as silent, \
                socket.create_connection(("127.0.0.1", port), timeout=5) as half:
            half.sendall(b"HELF\x40\x00")  # the start of a Hello, never finished
            start = time.monotonic()
            assert closed_by_server(silent), "a silent connection was kept"
            assert closed_by_server(half), "a half-sent Hello kept its connection"
            print(f"\nidle connections closed after {time.monotonic() - start:.2f} s "
                  "(handshake 0.5 s)")
    finally:
        out.close()


def test_when_every_slot_is_an_activated_session_the_newcomer_is_refused():
    out = server(max_clients=2, handshake_s=60.0)
    clients: list[Client] = []
    try:
        clients = [connected(out.settings.endpoint) for _ in range(2)]
        with socket.create_connection(("127.0.0.1", port_of(out)), timeout=5) as third:
            assert closed_by_server(third), "a third connection was let in"
        assert [read_state(c) for c in clients] == [0, 0]  # nobody was pushed out
    finally:
        for c in clients:
            c.disconnect()
        out.close()


def test_accepted_sockets_detect_a_vanished_peer():
    """Keepalive and a user timeout: a peer gone without a FIN is closed within DEAD_PEER_S."""
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        with socket.create_connection(listener.getsockname()), listener.accept()[0] as sock:
            keep_alive(sock)
            assert sock.getsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE)
            if hasattr(socket, "TCP_KEEPIDLE"):  # Linux
                got = tuple(sock.getsockopt(socket.IPPROTO_TCP, getattr(socket, n))
                            for n in ("TCP_KEEPIDLE", "TCP_KEEPINTVL", "TCP_KEEPCNT"))
                assert got == KEEPALIVE
                assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_USER_TIMEOUT) == \
                    DEAD_PEER_S * 1000
