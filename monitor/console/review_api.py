"""The incident review's routes: the filtered (and grouped) list, its filters' choices, the
list as CSV, an incident marked reviewed (an operator's credential, audited) and an
incident's export as a zip.

``GET /api/incidents[?kind=&camera=&state=&cause=&since=&until=&reviewed=0|1&grouped=1&limit=]``
-> ``{"incidents": [...], "groups": [...]}`` (groups with ``grouped=1``, ``review.py``);
``GET /api/incidents/facets`` -> ``{"kinds", "cameras"}``; ``GET /api/incidents.csv?<filters>``;
``POST /api/incidents/{id}/reviewed`` (Basic credential, as ``PUT /api/zones/{id}``);
``GET /api/incidents/{id}/export`` -> ``incident-<id>.zip``.
"""

from __future__ import annotations

import functools
import re
import sqlite3
import tempfile
from collections.abc import Awaitable, Callable, Iterator
from typing import Protocol

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import Response, StreamingResponse
from starlette.routing import Route

from monitor.console.audit import AuditLog, bounded
from monitor.console.auth import basic_credentials
from monitor.console.incidents import IncidentSource
from monitor.console.responses import SECURITY_HEADERS, json_response
from monitor.console.review import (
    BadFilter,
    check_incident_id,
    group_incidents,
    parse_filters,
    to_csv,
)
from monitor.console.setup_routes import forbidden
from monitor.console.sources import Source, request_source
from monitor.console.zones_api import ZoneEditor


class ReviewSources(Protocol):
    """What the review routes read of the console (``app.Console``): its incident source, its
    audit log and its zone editor (for the cameras of the cell). A protocol, so that this module
    never imports the app that mounts its routes."""

    @property
    def incidents(self) -> IncidentSource: ...

    @property
    def audit(self) -> AuditLog: ...

    @property
    def editor(self) -> ZoneEditor: ...


Login = Callable[[Source, tuple[str, str] | None], Awaitable[tuple[str | None, int, str]]]
REVIEWED_EVENT = "incident_reviewed"
CHUNK = 256 * 1024


def _chunks(spool) -> Iterator[bytes]:
    try:
        spool.seek(0)
        while chunk := spool.read(CHUNK):
            yield chunk
    finally:
        spool.close()


def review_routes(console: ReviewSources, login: Login) -> list[Route]:
    """The routes, over the console's incident source and audit log; ``login``: the
    console's credential check (lock-outs and all, ``app.build_app``)."""

    def query(request: Request):
        return parse_filters(request.query_params.multi_items())

    async def incidents(request: Request) -> Response:
        try:
            q = query(request)
        except BadFilter as exc:
            return json_response({"error": str(exc)}, 400)
        rows = await run_in_threadpool(console.incidents.list, q.filters)
        body: dict = {"incidents": rows}
        if q.grouped:
            body["groups"] = [g.to_dict() for g in group_incidents(rows)]
        return json_response(body)

    async def facets(request: Request) -> Response:
        found = await run_in_threadpool(console.incidents.facets)
        cameras = sorted({*found["cameras"], *console.editor.cell().cameras})
        return json_response({"kinds": found["kinds"], "cameras": cameras})

    async def as_csv(request: Request) -> Response:
        try:
            q = query(request)
        except BadFilter as exc:
            return json_response({"error": str(exc)}, 400)
        rows = await run_in_threadpool(console.incidents.list, q.filters)
        return Response(to_csv(rows), media_type="text/csv; charset=utf-8", headers={
            **SECURITY_HEADERS,
            "content-disposition": 'attachment; filename="incidents.csv"'})

    async def reviewed(request: Request) -> Response:
        raw_id = request.path_params["id"]
        credentials = basic_credentials(request.headers.get("authorization"))
        source = request_source(request, console.trusted_proxies)
        client = source.fields()  # the socket's peer, and a trusted proxy's word apart
        operator, status, why = await login(source, credentials)
        if operator is None:
            # whoever reaches the port: one bounded, rate-limited audit line, nothing marked
            await run_in_threadpool(functools.partial(
                console.audit.refused, event=REVIEWED_EVENT, incident=raw_id, operator=None,
                tried=credentials[0] if credentials else None, **client,
                result="refused", error=why))
            headers = {"retry-after": "60"} if status in (429, 503) else {}
            return json_response({"error": why}, status, headers)
        refused = await forbidden(console, operator, "mark_reviewed", source, raw_id,
                                  SECURITY_HEADERS)
        if refused is not None:  # a viewer: 403 naming the level needed, audited
            return refused
        try:
            incident_id = check_incident_id(raw_id)
        except BadFilter as exc:
            await run_in_threadpool(functools.partial(
                console.audit.record, event=REVIEWED_EVENT, incident=bounded(raw_id, 80),
                operator=operator, **client, result="bad_request", error=str(exc)))
            return json_response({"error": str(exc)}, 400)
        try:
            mark = await run_in_threadpool(console.incidents.mark_reviewed, incident_id,
                                           operator)
        except (OSError, sqlite3.Error) as exc:
            text = f"the review mark could not be written: {type(exc).__name__}: " \
                   f"{str(exc).splitlines()[0] if str(exc) else ''}"
            await run_in_threadpool(functools.partial(
                console.audit.record, event=REVIEWED_EVENT, incident=incident_id,
                operator=operator, **client, result="error", error=text))
            return json_response({"error": text}, 500)
        if mark is None:
            await run_in_threadpool(functools.partial(
                console.audit.record, event=REVIEWED_EVENT, incident=incident_id,
                operator=operator, **client, result="unknown"))
            return json_response({"error": f"no incident {incident_id!r}"}, 404)
        entry = await run_in_threadpool(functools.partial(
            console.audit.record, event=REVIEWED_EVENT, incident=incident_id,
            operator=operator, **client, result="reviewed",
            reviewed_by=mark.operator, reviewed_at=mark.at))
        return json_response({"reviewed": incident_id, "review": mark.to_dict(),
                              "audit": entry})

    async def export(request: Request) -> Response:
        try:
            incident_id = check_incident_id(request.path_params["id"])
        except BadFilter as exc:
            return json_response({"error": str(exc)}, 400)
        parts = await run_in_threadpool(console.incidents.export, incident_id)
        if parts is None:
            return json_response({"error": f"no incident {incident_id!r}"}, 404)
        # written to a spooled file (a clip is a few MB: held in memory up to 16 MB, on disk
        # beyond), then streamed
        # closed by _chunks once streamed
        spool = tempfile.SpooledTemporaryFile(max_size=16 * 2**20)  # noqa: SIM115
        try:
            await run_in_threadpool(parts.write_zip, spool)
        except OSError as exc:  # a clip deleted by retention while it was read
            spool.close()
            return json_response({"error": f"the export could not be written: {exc}"}, 500)
        headers = {**SECURITY_HEADERS,
                   "content-disposition": f'attachment; filename="incident-{incident_id}.zip"'}
        if parts.missing:
            text = "; ".join(f"{name}: {why}" for name, why in parts.missing)
            # a header is one line of printable ASCII (a record may name anything)
            headers["x-incident-missing"] = re.sub(r"[^\x20-\x7e]", "?", str(bounded(text, 400)))
        return StreamingResponse(_chunks(spool), media_type="application/zip",
                                 headers=headers)

    return [
        Route("/api/incidents", incidents),
        Route("/api/incidents.csv", as_csv),
        Route("/api/incidents/facets", facets),
        Route("/api/incidents/{id}/reviewed", reviewed, methods=["POST"]),
        Route("/api/incidents/{id}/export", export),
    ]
