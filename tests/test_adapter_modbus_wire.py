"""The Modbus TCP server of `monitor bridge plc` on the wire (monitor/adapters/modbus_server.py):
requests pipelined in one TCP segment are all answered, in order, writes included; a request
split over two segments survives an answer going out in between. A real pymodbus server in
this process, a raw socket as the client."""

from __future__ import annotations

import socket
import struct
import time

import pytest

pytest.importorskip("pymodbus")

from monitor.adapters import modbus_map as mm
from monitor.adapters.modbus import ModbusOutput
from monitor.adapters.snapshot import snapshot_of
from monitor.wire.consumer import Verdict
from tests.helpers import free_port

WATCHDOG = mm.ADDRESS["plc_watchdog"]


@pytest.fixture(scope="module")
def server():
    out = ModbusOutput("127.0.0.1", free_port(), state=mm.AdapterState(stale_s=3600.0),
                       watchdog_s=0).start()
    cmd = {"state": "RUN", "speed_scale": 1.0, "reasons": []}
    now = time.monotonic()
    out.publish(snapshot_of(Verdict("RUN", 1.0, "", 5, cmd), now, time.time(), 7, now))
    try:
        yield out
    finally:
        out.close()


def frame(tid: int, pdu: bytes, unit: int = 1) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def read_regs(fc: int = 3, start: int = 0, count: int = mm.SIZE) -> bytes:
    return struct.pack(">BHH", fc, start, count)


def write_one(address: int, value: int) -> bytes:
    return struct.pack(">BHH", 6, address, value)


def write_many(address: int, *values: int) -> bytes:
    return struct.pack(f">BHHB{len(values)}H", 16, address, len(values), 2 * len(values),
                       *values)


def answers(sock: socket.socket, n: int, timeout: float = 20.0) -> list[tuple[int, bytes]]:
    """The first ``n`` answers as (transaction id, PDU); fails naming how many came."""
    sock.settimeout(0.2)
    got, data = [], b""
    deadline = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < deadline:
        try:
            chunk = sock.recv(65536)
        except TimeoutError:
            continue
        if not chunk:
            break
        data += chunk
        while len(data) >= 6 and len(data) >= 6 + int.from_bytes(data[4:6], "big"):
            size = 6 + int.from_bytes(data[4:6], "big")
            got.append((int.from_bytes(data[:2], "big"), data[7:size]))
            data = data[size:]
    assert len(got) == n, f"{len(got)} of {n} answers arrived: {got}"
    return got


def pipelined(n: int) -> list[tuple[bytes, bytes | None]]:
    """``n`` requests mixing reads, writes, a refused write and a read beyond the map; each
    with the answer PDU expected (None: a read, checked by the caller)."""
    reqs: list[tuple[bytes, bytes | None]] = []
    for i in range(n):
        value = 100 + i
        kind = i % 5
        if kind == 0:
            reqs.append((read_regs(3), None))
        elif kind == 1:  # the echo of a single write is the request itself
            reqs.append((write_one(WATCHDOG, value), write_one(WATCHDOG, value)))
        elif kind == 2:
            reqs.append((read_regs(4), None))
        elif kind == 3:
            reqs.append((write_many(WATCHDOG, value), struct.pack(">BHH", 16, WATCHDOG, 1)))
        else:
            reqs.append((write_one(mm.ADDRESS["state"], 2),  # read-only: exception 02
                         bytes([6 | 0x80, mm.ILLEGAL_ADDRESS])))
    return reqs


@pytest.mark.parametrize("n", [2, 5, 20])
def test_every_request_of_a_segment_is_answered_in_order_writes_included(server, n):
    reqs = pipelined(n)
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
        s.sendall(frame(0, write_one(WATCHDOG, 1)))  # a known value before the segment
        assert answers(s, 1)[0][0] == 0
        s.send(b"".join(frame(i + 1, pdu) for i, (pdu, _) in enumerate(reqs)))  # one send()
        got = answers(s, n)
    assert [tid for tid, _ in got] == list(range(1, n + 1))
    watchdog = 1  # each read sees exactly the writes sent before it, none after it
    for (pdu, expected), (_, answer) in zip(reqs, got, strict=True):
        if expected is not None:
            assert answer == expected
            if pdu[0] in (6, 16) and answer[0] < 0x80:
                watchdog = int.from_bytes(pdu[3:5] if pdu[0] == 6 else pdu[6:8], "big")
        else:
            assert answer[:2] == bytes([pdu[0], 2 * mm.SIZE])
            regs = struct.unpack(f">{mm.SIZE}H", answer[2:])
            assert regs[mm.ADDRESS["state"]] == 2 and regs[WATCHDOG] == watchdog


def test_a_request_split_over_two_segments_survives_an_answer_in_between(server):
    first, second = frame(1, write_one(WATCHDOG, 4321)), frame(2, read_regs(3))
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        s.send(first + second[:5])  # the second request's header is cut
        assert answers(s, 1) == [(1, write_one(WATCHDOG, 4321))]  # answered meanwhile
        s.send(second[5:])
        (tid, answer), = answers(s, 1)
    regs = struct.unpack(f">{mm.SIZE}H", answer[2:])
    assert tid == 2 and regs[WATCHDOG] == 4321


def test_a_segment_that_is_no_modbus_closes_only_that_connection(server):
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as bad:
        bad.send(frame(1, read_regs(3)) + b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        assert answers(bad, 1)[0][0] == 1  # the request before the junk is still answered
        bad.settimeout(20.0)
        assert bad.recv(1024) == b""  # then the server closes: no frame boundary is left
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
        s.send(frame(9, read_regs(3)))
        assert answers(s, 1)[0][0] == 9
