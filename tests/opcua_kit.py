"""OPC UA test clients (asyncua's sync client) that connect exactly once.

asyncua's sync ``Client.__enter__`` connects again: ``with connect(url) as c`` on a client that
``connect`` already connected opened a second TCP connection (and session) and left the first
one behind, so a test that meant 5 clients held 9 connections."""

from __future__ import annotations

import contextlib

from asyncua.sync import Client


class ConnectedClient(Client):
    """A client connected by ``connected``; ``with`` only disconnects it at the end."""

    def __enter__(self) -> ConnectedClient:
        return self


def connected(client: ConnectedClient) -> ConnectedClient:
    """``client`` connected; if that fails, its loop thread stopped (else pytest never exits)."""
    try:
        client.connect()
    except BaseException:
        with contextlib.suppress(Exception):
            client.disconnect()
        raise
    return client
