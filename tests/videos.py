"""MP4 surgery for the tests: move the index to the front (faststart) so a cut file stays
readable up to the cut."""

from __future__ import annotations

import struct
from pathlib import Path


def _boxes(data: bytes | bytearray, start: int, end: int):
    i = start
    while i < end:
        size, kind = struct.unpack(">I4s", data[i:i + 8])
        head = 8
        if size == 1:
            size, head = struct.unpack(">Q", data[i + 8:i + 16])[0], 16
        elif size == 0:
            size = end - i
        yield kind.decode("latin1"), i, size, head
        i += size


def faststart(path: Path) -> Path:
    """Move the MP4 'moov' index before 'mdat' (as ``-movflags faststart`` does) so a cut file
    keeps its index; chunk offsets (stco/co64) shift by the size of moov."""
    data = bytearray(path.read_bytes())
    top = {k: (o, s) for k, o, s, _ in _boxes(data, 0, len(data))}
    offset, size = top["moov"]
    moov = bytearray(data[offset:offset + size])

    def patch(start: int, end: int) -> None:
        for kind, o, s, head in _boxes(moov, start, end):
            if kind in ("trak", "mdia", "minf", "stbl"):
                patch(o + head, o + s)
            elif kind in ("stco", "co64"):
                width, fmt = (4, ">I") if kind == "stco" else (8, ">Q")
                (count,) = struct.unpack(">I", moov[o + 12:o + 16])
                for k in range(count):
                    p = o + 16 + width * k
                    struct.pack_into(fmt, moov, p, struct.unpack(fmt, moov[p:p + width])[0] + size)

    patch(8, len(moov))
    out = bytearray()
    for kind, o, s, _ in _boxes(data, 0, len(data)):
        if kind == "mdat":
            out += moov
        if kind != "moov":
            out += data[o:o + s]
    path.write_bytes(bytes(out))
    return path
