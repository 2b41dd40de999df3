"""Outputs for the robot side: the consumer rule once, many protocols.

The monitor publishes signed commands over Zenoh; a robot controller that cannot run Zenoh and
Ed25519 itself (a PLC, a ROS 2 cell) gets them from an adapter process, ``monitor bridge
plc|opcua|ros2``. The adapter follows the commands with the reference consumer
(``monitor.wire.consumer.CommandWatchdog``: signature, cell, boot, seq, ttl, liveliness, clock
window) in ``follower.py`` and hands each output one ``SafetySnapshot`` (``snapshot.py``) per
tick: silence, a bad signature or a stale command is STOP on every output within the same
budget as ``monitor watch``. An output never decides anything itself.

These are optional extras around the safety loop: the monitor never waits for them, and killing
an adapter never changes a command (its outputs then carry their own age and stop changing,
which the robot side must treat as STOP: docs/adapters.md).

Owns: the follower (``follower.py``), the snapshot every output reads (``snapshot.py``) and one
module per protocol (Modbus TCP, OPC UA, ROS 2). May import: ``monitor.bus``, ``monitor.wire``,
``monitor.cases``, ``monitor.pose`` and the layers under them; each protocol module stands alone (an
independence contract); never the service, the replay or the cli.
"""

from monitor.adapters.snapshot import Output, SafetySnapshot, snapshot_of

__all__ = ["Output", "SafetySnapshot", "snapshot_of"]
