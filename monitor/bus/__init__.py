"""The monitor's live Zenoh edge: commands, heartbeat, alerts, status, resets, holds, preview.

Owns: the session that publishes signed commands and answers resets and mutes
(``session.SafetyBus``), one monitor per cell (``peers``), the reset desk (``reset_desk``),
the desk of acceptances of objects (``accept_desk``, on ``monitor.wire.request_desk``),
hand-over holds between the monitors of a cell (``holds``), commands on the cell's key that this
monitor did not send (``foreign``) and the console's bounded live picture (``preview``).

May import: ``monitor.wire`` (formats, signatures, the consumer rule), ``monitor.cases`` (mute
requests), ``monitor.tracking`` (the hand-over it carries), ``monitor.pose``, ``monitor.policy``
and the bottom layer. Never the pipeline's callers (driver, service, replay, cli).
"""

from monitor.bus.session import ALERT_SCHEMA, STATUS_SCHEMA, SafetyBus

__all__ = ["ALERT_SCHEMA", "STATUS_SCHEMA", "SafetyBus"]
