"""The OTUS tracker's UDP datagram: one pose as 23 little-endian doubles, 184 bytes.

Order: device id, timestamp, position xyz, linear velocity xyz, linear acceleration xyz,
orientation quaternion xyzw, angular velocity xyz, angular acceleration xyz, button 1, button 2
(table: docs/otus.md; the ZČU Plzeň tracker report, 2018). Units are taken as SI: metres,
seconds (the tracker's own clock), radians. Only the codec lives here, below everything that
judges a sample (``monitor.pose.stream``: plausibility, the Zenoh samples; ``monitor.pose.
tool_motion``: the tool's speed), so both can name the sample without importing each other.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from monitor.errors import InputError

OTUS_FORMAT = "<23d"
OTUS_SIZE = struct.calcsize(OTUS_FORMAT)  # 184

REJECT_REASONS = (
    "size",  # datagram is not 184 bytes
    "non_finite",  # a NaN or infinity in any field
    "quaternion_norm",  # |q| differs from 1 by more than the tolerance
    "timestamp_backwards",
    "timestamp_repeat",
    "speed",  # implied (position jump) or reported linear speed above the limit
    "acceleration",  # implied (velocity change) or reported acceleration above the limit
    "angular_speed",  # implied (orientation jump) or reported angular speed above the limit
    "out_of_bounds",  # position outside the configured tracking volume
    "malformed",  # a Zenoh pose sample that is not valid JSON of the schema
    "silence",  # no packet for longer than pose_timeout (reported by the bridge, once per gap)
)

Vec3 = tuple[float, float, float]


class PacketError(InputError):
    """A pose packet or sample that cannot be used; ``reason`` is one of ``REJECT_REASONS``."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class OtusSample:
    """One tracker pose. Metres, seconds (tracker clock), radians; quaternion is x, y, z, w."""

    device_id: float
    timestamp: float
    position_m: Vec3
    velocity_m_s: Vec3
    acceleration_m_s2: Vec3
    quaternion_xyzw: tuple[float, float, float, float]
    angular_velocity_rad_s: Vec3
    angular_acceleration_rad_s2: Vec3
    button1: float = 0.0
    button2: float = 0.0

    def values(self) -> tuple[float, ...]:
        """The 23 doubles in packet order."""
        return (self.device_id, self.timestamp, *self.position_m, *self.velocity_m_s,
                *self.acceleration_m_s2, *self.quaternion_xyzw, *self.angular_velocity_rad_s,
                *self.angular_acceleration_rad_s2, self.button1, self.button2)


def encode_otus(sample: OtusSample) -> bytes:
    """Pack a sample into the 184-byte OTUS datagram."""
    return struct.pack(OTUS_FORMAT, *sample.values())


def sample_from_values(v: tuple[float, ...] | list[float]) -> OtusSample:
    return OtusSample(
        device_id=v[0], timestamp=v[1], position_m=(v[2], v[3], v[4]),
        velocity_m_s=(v[5], v[6], v[7]), acceleration_m_s2=(v[8], v[9], v[10]),
        quaternion_xyzw=(v[11], v[12], v[13], v[14]),
        angular_velocity_rad_s=(v[15], v[16], v[17]),
        angular_acceleration_rad_s2=(v[18], v[19], v[20]), button1=v[21], button2=v[22],
    )


def decode_otus(packet: bytes) -> OtusSample:
    """Unpack one OTUS datagram. Raises ``PacketError("size")`` unless it is 184 bytes; the
    values are not checked here (``PoseValidator`` does that)."""
    if len(packet) != OTUS_SIZE:
        raise PacketError("size", f"OTUS packet has {len(packet)} bytes, expected {OTUS_SIZE}")
    return sample_from_values(struct.unpack(OTUS_FORMAT, packet))
