"""rmw_zenoh's wire format, written without ROS: key expressions, liveliness tokens, the
attachment and CDR for the three message types the ROS 2 output publishes (docs/ros2.md).

Pure functions only. The format follows ros2/rmw_zenoh (docs/design.md and
``attachment_helpers.cpp``) as released in Jazzy >= 0.2.4 and Humble >= 0.1.2:

- data key: ``<domain>/<topic without leading slash>/<pkg>::msg::dds_::<Name>_/<RIHS01_...>``;
- payload: CDR little-endian with the 4-byte encapsulation header ``00 01 00 00``;
- attachment: int64 sequence number, int64 source timestamp (ns since the epoch), LEB128 length
  16, the 16-byte GID (33 bytes; zenoh-ext's serializer, little-endian);
- liveliness tokens ``@ros2_lv/<domain>/<zid>/<nid>/<id>/<NN|MP>/<enclave>/<namespace>/<node>
  [/<topic>/<type>/<hash>/<qos>]`` with ``/`` mangled to ``%`` (empty: ``%``).

The CDR encoder is our own (three fixed types, no dependency at run time); the tests decode its
output with rosbags and compare the type hashes below with rosbags' RIHS01.
"""

from __future__ import annotations

import hashlib
import re
import struct
from dataclasses import dataclass

CDR_LE_HEADER = b"\x00\x01\x00\x00"  # CDR_LE, options 0
ADMIN_SPACE = "@ros2_lv"
GID_SIZE = 16
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE

# ROS type -> RIHS01 type hash (REP-2016). Checked against rosbags' hash_rihs01 in the tests
# and against rmw_zenoh's design doc for std_msgs/msg/String.
TYPE_HASHES = {
    "std_msgs/msg/Float64":
        "RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a",
    "std_msgs/msg/String":
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "diagnostic_msgs/msg/DiagnosticArray":
        "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
}

# Humble has no type hashes (REP-2016 came with Iron): its rmw_zenoh writes this in their place
NO_TYPE_HASH = "TypeHashNotSupported"
DISTROS = ("jazzy", "humble")  # jazzy: also Kilted and Rolling (RIHS01 hashes)

# diagnostic_msgs/msg/DiagnosticStatus levels
DIAG_OK, DIAG_WARN, DIAG_ERROR, DIAG_STALE = 0, 1, 2, 3

_SEGMENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def dds_type(ros_type: str) -> str:
    """``std_msgs/msg/Float64`` -> ``std_msgs::msg::dds_::Float64_`` (rmw_zenoh's type name)."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def is_ros_name(name: str, absolute: bool) -> bool:
    """A valid ROS 2 name: segments of ``[A-Za-z_][A-Za-z0-9_]*`` joined by ``/`` (absolute:
    with one leading ``/``)."""
    if absolute:
        if not name.startswith("/"):
            return False
        name = name[1:]
    return bool(name) and all(_SEGMENT.fullmatch(s) for s in name.split("/"))


def ros_segment(text: str) -> str:
    """``text`` made a valid name segment (cell ids may hold ``-`` or start with a digit)."""
    seg = re.sub(r"[^A-Za-z0-9_]", "_", text) or "_"
    return seg if _SEGMENT.fullmatch(seg) else "_" + seg


def mangle(name: str) -> str:
    """rmw_zenoh's mangling inside liveliness tokens: ``/`` -> ``%``; empty -> ``%``."""
    return name.replace("/", "%") if name else "%"


def type_hash(ros_type: str, distro: str = "jazzy") -> str:
    return NO_TYPE_HASH if distro == "humble" else TYPE_HASHES[ros_type]


def data_key(domain: int, topic: str, ros_type: str, distro: str = "jazzy") -> str:
    """The key expression a ROS 2 subscriber of ``topic`` listens on."""
    return f"{domain}/{topic.lstrip('/')}/{dds_type(ros_type)}/{type_hash(ros_type, distro)}"


def qos_string(depth: int) -> str:
    """rmw_zenoh's QoS chunk of a token for RELIABLE, VOLATILE, KEEP_LAST(depth), no deadline,
    lifespan or lease, AUTOMATIC liveliness: components equal to rmw_zenoh's defaults are
    empty, so only the depth is written."""
    return f"::,{depth}:,:,:,,"


def node_token(domain: int, zid: str, node_id: int, namespace: str, node: str) -> str:
    return f"{ADMIN_SPACE}/{domain}/{zid}/{node_id}/{node_id}/NN/%/{mangle(namespace)}/{node}"


def publisher_token(domain: int, zid: str, node_id: int, entity_id: int, namespace: str,
                    node: str, topic: str, ros_type: str, depth: int,
                    distro: str = "jazzy") -> str:
    return (f"{ADMIN_SPACE}/{domain}/{zid}/{node_id}/{entity_id}/MP/%/{mangle(namespace)}/"
            f"{node}/{mangle(topic)}/{dds_type(ros_type)}/{type_hash(ros_type, distro)}/"
            f"{qos_string(depth)}")


def gid_of(token: str) -> bytes:
    """A 16-byte GID unique to a publisher's token. rmw_zenoh hashes the token with XXH3-128;
    we use BLAKE2b-128 (no extra dependency): unique and stable, but not the same bytes."""
    return hashlib.blake2b(token.encode(), digest_size=GID_SIZE).digest()


def attachment(seq: int, timestamp_ns: int, gid: bytes) -> bytes:
    """The attachment every rmw_zenoh sample must carry (samples without it are dropped)."""
    if len(gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(gid)}")
    return struct.pack("<qqB", seq, timestamp_ns, GID_SIZE) + gid


@dataclass(frozen=True)
class Attachment:
    seq: int
    timestamp_ns: int
    gid: bytes


def parse_attachment(data: bytes) -> Attachment:
    """The inverse of ``attachment``; ValueError on any other layout."""
    if len(data) != ATTACHMENT_SIZE or data[16] != GID_SIZE:
        raise ValueError(f"not an rmw_zenoh attachment ({len(data)} bytes)")
    seq, ts = struct.unpack_from("<qq", data)
    return Attachment(seq, ts, bytes(data[17:]))


class _Cdr:
    """Little-endian CDR (XCDR1) writer; alignment is relative to the end of the header."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def _align(self, n: int) -> None:
        self.buf += b"\x00" * (-len(self.buf) % n)

    def u8(self, v: int) -> None:
        self.buf += struct.pack("<B", v)

    def u32(self, v: int) -> None:
        self._align(4)
        self.buf += struct.pack("<I", v)

    def i32(self, v: int) -> None:
        self._align(4)
        self.buf += struct.pack("<i", v)

    def f64(self, v: float) -> None:
        self._align(8)
        self.buf += struct.pack("<d", v)

    def string(self, s: str) -> None:
        raw = s.encode("utf-8").replace(b"\x00", b"")  # a NUL would end the string early
        self.u32(len(raw) + 1)
        self.buf += raw + b"\x00"

    def done(self) -> bytes:
        return CDR_LE_HEADER + bytes(self.buf)


def cdr_float64(value: float) -> bytes:
    w = _Cdr()
    w.f64(value)
    return w.done()


def cdr_string(text: str) -> bytes:
    w = _Cdr()
    w.string(text)
    return w.done()


@dataclass(frozen=True)
class DiagnosticStatus:
    level: int
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...] = ()


def cdr_diagnostic_array(stamp_ns: int, frame_id: str,
                         statuses: tuple[DiagnosticStatus, ...]) -> bytes:
    """diagnostic_msgs/msg/DiagnosticArray: std_msgs/Header (builtin_interfaces/Time sec,
    nanosec; frame_id), then the sequence of DiagnosticStatus (level byte, name, message,
    hardware_id, sequence of KeyValue)."""
    w = _Cdr()
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    w.i32(sec)
    w.u32(nanosec)
    w.string(frame_id)
    w.u32(len(statuses))
    for st in statuses:
        w.u8(st.level)
        w.string(st.name)
        w.string(st.message)
        w.string(st.hardware_id)
        w.u32(len(st.values))
        for key, value in st.values:
            w.string(key)
            w.string(value)
    return w.done()
