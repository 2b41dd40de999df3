"""The incident review's logic, pure (no I/O): the list's filters read from a query string,
repeated alerts grouped into one row, the list as CSV.

Filters (``parse_filters``): every parameter is checked before anything reads the index; a bad
one is a ``BadFilter`` with one line naming it (an HTTP 400), never an unfiltered list: an
operator who mistypes ``kind=zone_mutd`` must not believe there were no mutes, and one who
mistypes the parameter's name must not be shown everything as if it were the filtered list.

Grouping (``group_incidents``): consecutive incidents in the list (newest first) of the same
kind, camera and zone, each within ``GROUP_WINDOW_S`` of its neighbour, are one group, shown
as one row "N× kind" that expands. Consecutive *in the list*: any other incident in between
ends the group, so the list stays in time order and a group never hides a different incident
(a STOP between two mutes stays its own row between them). A chattering alert (issue 32: 177
incidents in 45 minutes, mostly the same alert) becomes one row however long it chatters.
"""

from __future__ import annotations

import csv
import io
import math
import re
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

GROUP_WINDOW_S = 60.0  # neighbours at most this far apart join a group
MAX_LISTED = 500  # a page, not the whole history
STATES = ("STOP", "SLOW", "RUN")
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")  # a kind, cause or camera id
INCIDENT_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")
FILTERS = ("kind", "cause", "state", "camera", "since", "until", "reviewed", "grouped",
           "limit")
YES, NO = ("1", "true", "yes"), ("0", "false", "no")


class BadFilter(ValueError):
    """A filter the list refuses (one line)."""


@dataclass(frozen=True)
class IncidentFilters:
    """What the incident list is narrowed to (None: any). Times are Unix seconds; ``kind``: a
    cause (``stop``, ``zone_edit``) or an alert's kind (``zone_muted``); ``reviewed``: only
    reviewed (True) or only not reviewed (False) incidents."""

    cause: str | None = None
    state: str | None = None
    camera: str | None = None
    since: float | None = None
    until: float | None = None
    limit: int = MAX_LISTED
    kind: str | None = None
    reviewed: bool | None = None


@dataclass(frozen=True)
class ListQuery:
    """A parsed ``/api/incidents`` query: the filters and whether to group."""

    filters: IncidentFilters = field(default_factory=IncidentFilters)
    grouped: bool = False


def shown(text: str, limit: int = 24) -> str:
    """A value for a one-line message: short ones whole, long ones cut, with their length."""
    text = text.replace("\n", " ").replace("\r", " ")
    return repr(text) if len(text) <= limit else f"{text[:limit]!r}... ({len(text)} characters)"


def _name(key: str, value: str) -> str:
    if not NAME.match(value):
        raise BadFilter(f"{key} {shown(value)}: letters, digits, _ . - (at most 64), "
                        "starting with a letter or digit")
    return value


def _time(key: str, value: str) -> float:
    try:
        t = float(value)
    except ValueError:
        raise BadFilter(f"{key} {shown(value)}: Unix seconds") from None
    if not math.isfinite(t) or not 0 <= t < 1e11:
        raise BadFilter(f"{key} {shown(value)}: Unix seconds (0 to 1e11)")
    return t


def _flag(key: str, value: str) -> bool:
    if value.lower() in YES:
        return True
    if value.lower() in NO:
        return False
    raise BadFilter(f"{key} {shown(value)}: 1 or 0")


def parse_filters(params: Sequence[tuple[str, str]]) -> ListQuery:
    """The list's query from its parameters (name, value) in order; an empty value is no
    filter. BadFilter: an unknown name, a repeated one, a malformed value."""
    seen: dict[str, str] = {}
    for key, value in params:
        if key not in FILTERS:
            raise BadFilter(f"unknown filter {shown(key)}: one of {', '.join(FILTERS)}")
        if key in seen:
            raise BadFilter(f"filter {key} given twice")
        seen[key] = value
    got = {k: v for k, v in seen.items() if v != ""}
    state = got.get("state")
    if state is not None and state not in STATES:
        raise BadFilter(f"state {shown(state)}: one of {', '.join(STATES)}")
    limit = MAX_LISTED
    if "limit" in got:
        text = got["limit"]
        if not text.isdigit() or len(text) > 3 or not 1 <= int(text) <= MAX_LISTED:
            raise BadFilter(f"limit {shown(got['limit'])}: 1 to {MAX_LISTED}")
        limit = int(got["limit"])
    since = _time("since", got["since"]) if "since" in got else None
    until = _time("until", got["until"]) if "until" in got else None
    if since is not None and until is not None and since > until:
        raise BadFilter(f"since {since:g} is after until {until:g}")
    filters = IncidentFilters(
        cause=_name("cause", got["cause"]) if "cause" in got else None, state=state,
        camera=_name("camera", got["camera"]) if "camera" in got else None,
        since=since, until=until, limit=limit,
        kind=_name("kind", got["kind"]) if "kind" in got else None,
        reviewed=_flag("reviewed", got["reviewed"]) if "reviewed" in got else None)
    grouped = _flag("grouped", got["grouped"]) if "grouped" in got else False
    return ListQuery(filters, grouped)


def check_incident_id(value: str) -> str:
    """An incident id as the recorder and the console make them (BadFilter otherwise: a path
    like ``../../x`` never reaches a file name)."""
    if not INCIDENT_ID.match(value):
        raise BadFilter(f"incident id {shown(value)}: letters, digits, _ . - (at most 128)")
    return value


@dataclass(frozen=True)
class IncidentGroup:
    """Consecutive incidents of one kind, camera and zone (newest first): ``ids``; ``first``
    and ``last``: the oldest's and the newest's start (Unix s); ``reviewed``: how many of
    them are marked reviewed."""

    kind: str
    camera: str
    zone: str
    ids: tuple[str, ...]
    first: float
    last: float
    reviewed: int

    @property
    def count(self) -> int:
        return len(self.ids)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "camera": self.camera, "zone": self.zone,
                "count": self.count, "ids": list(self.ids), "first": self.first,
                "last": self.last, "reviewed": self.reviewed,
                "title": f"{self.count}× {self.kind}" + (f" {self.camera}" if self.camera
                                                          else "")
                         + (f" {self.zone}" if self.zone else "")}


def group_incidents(rows: Sequence[Mapping[str, Any]],
                    window_s: float = GROUP_WINDOW_S) -> list[IncidentGroup]:
    """The list's rows (newest first; each with ``id``, ``started``, ``kind``, ``camera``,
    ``zone``, ``reviewed``) as groups, in the same order (a lone incident: a group of one)."""
    groups: list[IncidentGroup] = []
    for row in rows:
        key = (str(row["kind"]), str(row["camera"]), str(row["zone"]))
        started = float(row["started"])
        last = groups[-1] if groups else None
        if (last is not None and (last.kind, last.camera, last.zone) == key
                and abs(last.first - started) <= window_s):
            groups[-1] = IncidentGroup(*key, (*last.ids, str(row["id"])), started, last.last,
                                       last.reviewed + int(bool(row.get("reviewed"))))
        else:
            groups.append(IncidentGroup(*key, (str(row["id"]),), started, started,
                                        int(bool(row.get("reviewed")))))
    return groups


CSV_COLUMNS = ("id", "started", "started_utc", "kind", "cause", "state", "camera", "zone",
               "reviewed", "reviewed_by", "reviewed_at", "operator", "describe")


def _cell(value: Any) -> str:
    text = "" if value is None else str(value)
    # a cell a spreadsheet would run as a formula (=, +, -, @) is kept as text
    return "'" + text if text[:1] in ("=", "+", "-", "@", "\t", "\r") else text


def to_csv(rows: Sequence[Mapping[str, Any]]) -> str:
    """The listed rows as CSV (one line each, ``CSV_COLUMNS``)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for row in rows:
        review = row.get("review") or {}
        started = float(row["started"])
        writer.writerow([_cell(v) for v in (
            row["id"], f"{started:.3f}",
            time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(started)), row.get("kind"),
            row.get("cause"), row.get("state"), row.get("camera"), row.get("zone"),
            int(bool(row.get("reviewed"))), review.get("operator"), review.get("at"),
            row.get("operator"), row.get("describe"))])
    return out.getvalue()
