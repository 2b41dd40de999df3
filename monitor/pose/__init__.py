"""The tool's pose from the cell's tracker: the OTUS codec, its clock and the tool's speed.

Owns: the OTUS UDP codec, plausibility checks and Zenoh pose samples (``stream``), tracker time
checked against receive time (``tracker_time``), tool speed measured from the pose stream
(``tool_motion``) and the tracker's declared noise (``tracker_noise``).

May import: ``monitor.geometry`` and the bottom layer (``types``, ``schema``, ``errors``).
"""

from monitor.pose.stream import (
    OtusBridge,
    OtusSample,
    PoseSubscriber,
    PoseValidator,
    decode_otus,
    encode_otus,
)

__all__ = [
    "OtusBridge",
    "OtusSample",
    "PoseSubscriber",
    "PoseValidator",
    "decode_otus",
    "encode_otus",
]
