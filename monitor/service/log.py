"""The service's log: one line per event (plain, or JSON with ``--log-json``) on stderr, and the
fields of a command change's line. Shared by the entry (``monitor.service.run``), its start-up
checks (``monitor.service.setup``) and the live loop (``monitor.service.loop``)."""

from __future__ import annotations

import json
import logging
import sys

from monitor.policy import Command, Reason
from monitor.timetext import TimeText

log = logging.getLogger("monitor")


class _JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        body = {"time": round(record.created, 3), "level": record.levelname.lower(),
                "event": record.getMessage()}
        body.update(getattr(record, "fields", {}))
        return json.dumps(body, default=str)


def setup_logging(as_json: bool) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_JsonFormatter() if as_json else
                         logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    log.handlers[:] = [handler]
    log.setLevel(logging.INFO)
    log.propagate = False


def command_fields(cmd: Command, when: TimeText, notice: Reason | None = None) -> dict:
    """The fields of a command change's log line: one ``describe`` (latch cause, what holds
    now, whether a reset is possible; times in ``when``'s clock), never a second list of
    reasons beside it that could say otherwise (the bus payload has them, as numbers)."""
    text = cmd.describe(when)
    if notice is not None:
        text += f" [{notice.message}]"
    return {"speed_scale": cmd.speed_scale, "latched": cmd.latched,
            "reset_possible": cmd.reset_possible, "describe": text}


def event(message: str, level: int = logging.INFO, /, **fields) -> None:
    """One line per event; fields go into the JSON object (or after the message).
    Positional-only, so a field may be called ``message`` (alerts have one)."""
    text = message if not fields else message + " " + " ".join(
        f"{k}={v}" for k, v in fields.items())
    log.log(level, text if not _json_logging() else message, extra={"fields": fields})


def _json_logging() -> bool:
    return any(isinstance(h.formatter, _JsonFormatter) for h in log.handlers)
