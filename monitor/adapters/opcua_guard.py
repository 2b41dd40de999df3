"""The OPC UA server's TCP connections, guarded: idle sockets never lock a real client out.

asyncua counts every TCP connection against ``max_connections`` from the moment it is accepted
and refuses the next one when the count is full; a connection that sends nothing is closed only
after 30 s (no ActivateSession). So 16 idle sockets locked every OPC UA client out for as long
as they were held. Here:

- a connection must activate a session within ``handshake_s`` (a real client needs a few ms for
  Hello, OpenSecureChannel, CreateSession and ActivateSession), else it is closed;
- when every slot is taken, a new connection takes the slot of the OLDEST connection that has
  not activated a session (it is closed), never the slot of an activated one; only when every
  slot holds an activated session is the newcomer refused;
- every accepted socket has TCP keepalive and a user timeout, so a peer that vanished without
  a FIN (a half-open connection, a pulled cable) is closed within ``DEAD_PEER_S``.

A flood of new connections faster than a real client's handshake can still push that client
out before it activates: the allow-list for that is the cell network (docs/opcua.md).

This module imports asyncua (the ``[opcua]`` extra); ``monitor.adapters.opcua`` imports it only
when the server is built. It uses asyncua 2.1's server internals (pinned ``<2.2``).
"""

from __future__ import annotations

import contextlib
import logging
import socket

from asyncua import Server
from asyncua.crypto import uacrypto
from asyncua.server.binary_server_asyncio import BinaryServer, OPCUAProtocol

log = logging.getLogger("monitor.adapters.opcua")

DEFAULT_HANDSHAKE_S = 3.0
# keepalive probes after 2 s of silence, every 1 s, 3 unanswered: closed; unacknowledged data
# for as long: closed too (TCP_USER_TIMEOUT)
KEEPALIVE = (2, 1, 3)
DEAD_PEER_S = KEEPALIVE[0] + KEEPALIVE[1] * KEEPALIVE[2]


def activated(conn: OPCUAProtocol) -> bool:
    session = conn.processor.session if conn.processor is not None else None
    return session is not None and session.is_activated()


def evictable(clients: list[OPCUAProtocol]) -> OPCUAProtocol | None:
    """The connection whose slot a newcomer takes when all are full: the oldest one without an
    activated session (``clients`` is in the order they came); None when all are activated."""
    return next((c for c in clients if not activated(c)), None)


def keep_alive(sock: socket.socket | None) -> None:
    """TCP keepalive and a user timeout on an accepted socket (Linux options where present)."""
    if sock is None:
        return
    idle, interval, count = KEEPALIVE
    options = [(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)]
    for name, value in (("TCP_KEEPIDLE", idle), ("TCP_KEEPINTVL", interval),
                        ("TCP_KEEPCNT", count), ("TCP_USER_TIMEOUT", DEAD_PEER_S * 1000)):
        if hasattr(socket, name):
            options.append((socket.IPPROTO_TCP, getattr(socket, name), value))
    for level, option, value in options:
        with contextlib.suppress(OSError):  # a platform without it: the handshake limit holds
            sock.setsockopt(level, option, value)


class GuardedProtocol(OPCUAProtocol):
    def connection_made(self, transport) -> None:
        keep_alive(transport.get_extra_info("socket"))
        if len(self.clients) >= self.iserver.max_connections:
            victim = evictable(self.clients)
            if victim is not None:
                log.warning("OPC UA: all %d connections taken: closing %s (no session "
                            "activated) for a new client from %s", self.iserver.max_connections,
                            victim.peer_name, transport.get_extra_info("peername"))
                self.clients.remove(victim)  # its slot is free now, not once it has closed
                if victim.transport is not None:
                    victim.transport.close()
        super().connection_made(transport)


class GuardedBinaryServer(BinaryServer):
    def _make_protocol(self) -> OPCUAProtocol:
        return GuardedProtocol(iserver=self.iserver, policies=self._policies,
                               clients=self.clients, closing_tasks=self.closing_tasks,
                               limits=self.limits)


class GuardedServer(Server):
    """asyncua's Server with the guarded connections; ``handshake_s``: the time a connection
    has to activate a session."""

    def __init__(self, *args, handshake_s: float = DEFAULT_HANDSHAKE_S, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.iserver.max_pending_activation_seconds = handshake_s

    async def start(self) -> None:
        """asyncua 2.1's ``Server.start`` with ``GuardedBinaryServer``."""
        if self.iserver.certificate is not None:
            uacrypto.check_certificate(self.iserver.certificate, self._application_uri,
                                       socket.gethostname())
        await self._setup_server_nodes()
        await self.iserver.start()
        try:
            host, port = self._get_bind_socket_info()
            self.bserver = GuardedBinaryServer(self.iserver, host, port, self.limits)
            self.bserver.set_policies(self._policies)
            await self.bserver.start()
        except Exception:
            await self.iserver.stop()
            raise
