"""The pymodbus TCP server of `monitor bridge plc`, answering every request of a segment in order.

pymodbus 3.16's request handler decodes one frame per received segment, answers it later from
``last_pdu`` (shared by every request of the connection) and clears its receive buffer when it
sends an answer: a client that pipelines requests (several in one TCP segment, as PLC blocks
and gateways do) got one answer and lost the rest silently, writes included, and a request
split over two segments lost its beginning when an answer went out in between. Here every
complete frame of the buffer is decoded at once, queued, and answered in the order it came by
one task per connection; the buffer keeps the start of a split frame. A client that pipelines
faster than its answers go out is slowed down by TCP (reading pauses), never dropped.

This module imports pymodbus (the ``[plc]`` extra): ``monitor.adapters.modbus`` imports it only
when the server starts, and names the extra when it is missing.
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
from collections import deque

from pymodbus.constants import ExcCodes
from pymodbus.pdu import ExceptionResponse
from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler

# the client address of the request being answered (the write allow-list reads it)
PEER: contextvars.ContextVar[str] = contextvars.ContextVar("modbus_peer", default="")

MAX_PENDING = 256  # requests queued on one connection before reading pauses
# asyncio reads at most 256 KiB at a time; pymodbus drops a buffer above its limit (516 bytes)
# silently, so the limit is one read plus one split frame (a Modbus TCP frame is <= 260 bytes)
MAX_BUFFER = 256 * 1024 + 260


class OneLine(logging.Filter):
    """pymodbus's records as their first line: it appends its last raw frames to an error
    ("\n>>>>> recv: 0x0 0x1 ...") and a datastore error carries a whole traceback."""

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if "\n" in text:
            first = text.split("\n", 1)[0].removesuffix("Traceback (most recent call last):")
            record.msg, record.args = first.rstrip("; "), ()
        return True


def quiet_pymodbus() -> None:
    """pymodbus's own logger at warnings, one line each: its debug frame dumps and the dumps
    appended to its errors do not belong in the bridge's log."""
    logger = logging.getLogger("pymodbus.logging")
    logger.setLevel(logging.WARNING)
    if not any(isinstance(f, OneLine) for f in logger.filters):
        logger.addFilter(OneLine())


class PipelinedHandler(ServerRequestHandler):
    """One client connection: every complete frame decoded at once, answered in order."""

    def __init__(self, owner, trace_packet, trace_pdu, trace_connect) -> None:
        super().__init__(owner, trace_packet, trace_pdu, trace_connect)
        self.max_buffer_size = MAX_BUFFER
        self._pending: deque = deque()  # (pdu or an exception response to send as it is)
        self._wake = asyncio.Event()
        self._answering: asyncio.Task | None = None
        self._paused = False
        self._junk = False  # bytes that are no Modbus frame came: close once answered

    def callback_data(self, data: bytes, addr: tuple | None = None) -> int:
        """Queue every complete frame of ``data``; the bytes used (the rest is a split frame
        that waits for its next segment)."""
        used = 0
        while len(data) - used >= 8:
            if data[used + 2:used + 4] != b"\x00\x00":  # not Modbus: no frame boundary left
                self._junk = True  # answer what came before it, then close
                self.transport.pause_reading()
                used = len(data)
                break
            size = int.from_bytes(data[used + 4:used + 6], "big") + 6  # the MBAP length
            if len(data) - used < size:
                break  # the rest of this frame comes in a later segment
            tid, dev_id = int.from_bytes(data[used:used + 2], "big"), data[used + 6]
            body = data[used + 7:used + size]
            used += size
            if not body:
                continue
            pdu = self.framer.decoder.decode(body)
            if pdu is None:  # a function code pymodbus cannot decode: answered in its turn
                pdu = ExceptionResponse(body[0], exception_code=ExcCodes.ILLEGAL_FUNCTION,
                                        device_id=dev_id, transaction=tid)
            pdu.dev_id, pdu.transaction_id = dev_id, tid
            self._pending.append(self.trace_pdu(False, pdu))
        if self._junk and not self._pending:
            self.transport.close()
        elif self._pending:
            self._wake.set()
            if self._answering is None:
                self._answering = asyncio.get_running_loop().create_task(self._answer_all())
            if len(self._pending) >= MAX_PENDING and not self._paused and not self._junk:
                self._paused = True
                self.transport.pause_reading()
        return used

    async def _answer_all(self) -> None:
        peer = self.transport.get_extra_info("peername") if self.transport else None
        PEER.set(str(peer[0]) if peer else "")
        while True:
            await self._wake.wait()
            self._wake.clear()
            while self._pending:
                pdu = self._pending.popleft()
                if isinstance(pdu, ExceptionResponse):
                    self.server_send(pdu, None)
                else:
                    self.last_pdu, self.last_addr = pdu, None
                    await self.handle_request()
                if self._paused and len(self._pending) < MAX_PENDING // 2 and self.transport:
                    self._paused = False
                    self.transport.resume_reading()
            if self._junk and self.transport is not None:
                self.transport.close()
                return

    def send(self, data: bytes, addr: tuple | None = None) -> None:
        """An answer out, the receive buffer kept (pymodbus's ``send`` empties it)."""
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(data)

    def callback_disconnected(self, exc: Exception | None) -> None:
        if self._answering is not None:
            self._answering.cancel()
        self._pending.clear()
        super().callback_disconnected(exc)


class PipelinedServer(ModbusTcpServer):
    def callback_new_connection(self):
        return PipelinedHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)
