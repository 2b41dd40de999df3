"""``<prefix>safety/incidents``: a Zenoh queryable answering the incident list as JSON.

Parameters of the query (``?limit=20;cause=stop;since=<unix time>``) filter the list; the
answer is ``{"schema": "workcell.safety.incidents/1", "cell", "recorder", "incidents": [rows]}``
(rows as ``monitor incidents list --json``). It reads the index with its own read-only
connection in Zenoh's callback thread: never the safety loop's.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable

from monitor.incidents.store import IncidentIndex

SCHEMA = "workcell.safety.incidents/1"
DEFAULT_LIMIT = 100


def incidents_key(status_key: str) -> str:
    """The key beside the bus's ``safety/status``."""
    return status_key.rsplit("/", 1)[0] + "/incidents"


def answer(index: IncidentIndex, parameters: dict[str, str], cell: str, status: dict) -> dict:
    def number(name: str, kind=float):
        with contextlib.suppress(KeyError, TypeError, ValueError):
            return kind(parameters[name])
        return None

    limit = number("limit", int) or DEFAULT_LIMIT
    rows = [i.row() for i in index.list(since=number("since"), cause=parameters.get("cause"),
                                        limit=max(1, min(limit, 1000)))]
    return {"schema": SCHEMA, "cell": cell, "recorder": status, "incidents": rows}


def declare(session, key: str, index: IncidentIndex, cell: str,
            status: Callable[[], dict]):
    """Declare the queryable on ``session``; undeclare it (``.undeclare()``) before closing."""

    def on_query(query) -> None:
        with contextlib.suppress(Exception):  # a vanished querier must not kill the callback
            params = {k: str(v) for k, v in dict(query.parameters).items()}
            body = answer(index, params, cell, status())
            query.reply(key, json.dumps(body, default=str).encode(),
                        encoding="application/json")

    return session.declare_queryable(key, on_query)
