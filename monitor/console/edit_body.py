"""The zone editor's request, checked before anything reads it: every bad input is a
``BadRequest`` with a one-line message (an HTTP 400, audited), never an exception deeper in.

Why here and not in the zone validation: Python's JSON reader accepts what no zone file can
hold and what later code trips on. ``1e400`` reads as infinity, ``10**400`` as an integer that
``float()`` cannot convert (issue 31: an HTTP 500 and no audit line), ``NaN`` as a float that
compares false with every bound, a deeply nested array as a ``RecursionError``. So numbers are
checked as they are read (finite, within ``MAX_NUMBER``), the nesting depth and every string's
length are bounded, and only the editor's fields, with their types, are accepted.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

MAX_BODY = 256_000  # bytes
MAX_NUMBER = 1e6  # pixels and speed fractions are far below this
MAX_DEPTH = 6  # the body is {"points_px": [[x, y], ...]}: depth 3
MAX_TEXT = 200  # characters of a name, camera, kind or base
ZONE_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
TEXT_FIELDS = ("camera", "kind", "name", "base")
FIELDS = (*TEXT_FIELDS, "points_px", "speed_scale")


class BadRequest(ValueError):
    """A request the editor refuses before reading it further (one line)."""


def _short(text: str) -> str:
    return text if len(text) <= 24 else f"{text[:20]}... ({len(text)} characters)"


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:  # not reached for JSON's own number syntax
        raise BadRequest(f"number {_short(text)}: not a number") from None
    if not math.isfinite(value) or abs(value) > MAX_NUMBER:
        raise BadRequest(f"number {_short(text)}: out of range (at most {MAX_NUMBER:g} in "
                         "size)")
    return value


def _integer(text: str) -> int:
    if len(text) > 16:  # never converted: a 400-digit integer is no pixel
        raise BadRequest(f"number {_short(text)}: out of range (at most {MAX_NUMBER:g} in "
                         "size)")
    _number(text)
    return int(text)


def _constant(name: str) -> Any:
    raise BadRequest(f"{name}: not a number the editor accepts (finite numbers only)")


def _depth(value: Any, level: int = 1) -> int:
    if level > MAX_DEPTH:
        return level
    if isinstance(value, dict):
        return max((_depth(v, level + 1) for v in value.values()), default=level)
    if isinstance(value, list):
        return max((_depth(v, level + 1) for v in value), default=level)
    return level


def check_zone_id(zone_id: str) -> str:
    if not ZONE_ID.match(zone_id):
        raise BadRequest(f"zone id {_short(zone_id)!r}: letters, digits, _ . - (at most 64 "
                         "characters, starting with a letter or digit)")
    return zone_id


def parse_edit_body(raw: bytes, fields: tuple[str, ...] = FIELDS,
                    text_fields: tuple[str, ...] = TEXT_FIELDS) -> dict:
    """The editor's JSON object: only ``fields``, ``text_fields`` texts of at most ``MAX_TEXT``
    characters, finite numbers within ``MAX_NUMBER``, nested at most ``MAX_DEPTH`` deep (the
    setup page's edits name their own fields, ``monitor/console/setup_api.py``)."""
    if len(raw) > MAX_BODY:
        raise BadRequest(f"the body is {len(raw)} bytes: at most {MAX_BODY}")
    try:
        body = json.loads(raw, parse_float=_number, parse_int=_integer,
                          parse_constant=_constant)
    except BadRequest:
        raise
    except RecursionError:
        raise BadRequest(f"the JSON is nested too deeply (at most {MAX_DEPTH} levels)") from None
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        raise BadRequest(f"the body is not JSON: {str(exc).splitlines()[0][:120]}") from None
    if not isinstance(body, dict):
        raise BadRequest("the body is not a JSON object")
    if _depth(body) > MAX_DEPTH:
        raise BadRequest(f"the JSON is nested too deeply (at most {MAX_DEPTH} levels)")
    unknown = sorted(set(body) - set(fields))
    if unknown:
        raise BadRequest(f"unknown field {_short(unknown[0])!r} (the fields: "
                         f"{', '.join(fields)})")
    for name in text_fields:
        value = body.get(name)
        if value is None:
            continue
        if not isinstance(value, str):
            raise BadRequest(f"{name}: a text")
        if len(value) > MAX_TEXT:
            raise BadRequest(f"{name}: at most {MAX_TEXT} characters (got {len(value)})")
    speed = body.get("speed_scale")
    if speed is not None and (isinstance(speed, bool) or not isinstance(speed, int | float)):
        raise BadRequest("speed_scale: a number")
    return body
