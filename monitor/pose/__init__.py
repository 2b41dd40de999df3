"""The tool's pose from the cell's tracker: the OTUS codec, its clock and the tool's speed.

Owns: the OTUS UDP datagram (``otus``), plausibility checks and Zenoh pose samples
(``stream``), tracker time checked against receive time (``tracker_time``), tool speed measured
from the pose stream (``tool_motion``) and the tracker's declared noise (``tracker_noise``).

May import: ``monitor.geometry`` and the bottom layer (``types``, ``schema``, ``errors``).
"""

from monitor.pose.otus import OtusSample, decode_otus, encode_otus
from monitor.pose.stream import OtusBridge, PoseSubscriber, PoseValidator

__all__ = [
    "OtusBridge",
    "OtusSample",
    "PoseSubscriber",
    "PoseValidator",
    "decode_otus",
    "encode_otus",
]
