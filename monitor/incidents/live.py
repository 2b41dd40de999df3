"""The recorder in ``monitor run``: the sink, the ``safety/incidents`` queryable on the bus's
session, Prometheus counters per cause. An extra: it cannot stop the monitor from starting
(a broken data dir stops recording with an alert, as any later write error does)."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable

from monitor.incidents import IncidentIndex, data_dir_of, remote
from monitor.incidents.recorder import IncidentRecorder
from monitor.incidents.settings import config_hash
from monitor.timetext import wall_iso


def start_recorder(config, cell, bus, metrics, alert, event: Callable) -> tuple:
    """(the recorder sink, its close()): close after the bus's final STOP; bounded."""
    data_dir = data_dir_of(config.recorder)
    recorder = IncidentRecorder(
        config.recorder, data_dir, [c.id for c in config.cameras], cell,
        cell_id=bus.config.cell, config_hash=config_hash(config.source_file), on_alert=alert,
        on_incident=lambda causes: [metrics.incidents.labels(c).inc() for c in causes],
        when=wall_iso())  # live: descriptions and clips in local wall-clock time
    queryable = None
    key = remote.incidents_key(bus.keys.status)
    try:
        queryable = remote.declare(bus.session, key, IncidentIndex(data_dir), bus.config.cell,
                                   recorder.status)
    except Exception as exc:  # remote tools lose the list; recording and commands go on
        event("incidents queryable not declared", logging.WARNING, error=str(exc))
    event("recording incidents", data_dir=str(data_dir), key=key)

    def close() -> None:
        if queryable is not None:
            with contextlib.suppress(Exception):
                queryable.undeclare()
        recorder.close(timeout=2.0)

    return recorder, close
