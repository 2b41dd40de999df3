"""The console's web application (Starlette) and its process (uvicorn).

Why Starlette + uvicorn: a small ASGI toolkit (routing, static files, file responses with HTTP
ranges for video seeking) without a template engine, ORM or build step; uvicorn is its
reference server, with TLS built in. The pages are plain HTML and small scripts
(``static/console.js``, ``static/incidents.js``) that poll JSON: nothing to compile, nothing
fetched from the internet.

Routes: ``/`` live view, ``/incidents`` review (list, timeline, groups, playback), ``/zones``
zone editor (pages); ``/api/state``, ``/api/live/{camera}.jpg``,
``/api/incidents[?kind=&camera=&state=&cause=&since=&until=&reviewed=&grouped=&limit=]``,
``/api/incidents/facets``, ``/api/incidents.csv[?filters]``,
``/api/incidents/{id}/clip[?camera=]``, ``/api/incidents/{id}/thumb.jpg[?camera=]``,
``/api/incidents/{id}/export`` (a zip), ``/api/zones``, ``/api/zones/{camera}/image.jpg``
(read-only; no login on loopback); ``PUT /api/zones/{id}`` and
``POST /api/incidents/{id}/reviewed`` (an operator's credential; audited, accepted or
refused); ``POST /api/confirm-clear`` (an operator's confirm-clear after looking at the live
pictures, signed with their reset key: ``confirm_routes.py``). The incident review's routes
are in ``review_api.py``.
User levels and the setup page: ``setup_routes.py``; off loopback every ``GET`` of
``/api/`` needs a login (``sessions.py``).
"""

from __future__ import annotations

import functools
import sqlite3
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import anyio
import anyio.to_thread
import cv2
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from monitor.console.audit import AuditLog, bounded
from monitor.console.auth import Operators, basic_credentials
from monitor.console.confirm_clear import ConfirmClear
from monitor.console.confirm_routes import confirm_routes
from monitor.console.edit_body import MAX_BODY, BadRequest, check_zone_id, parse_edit_body
from monitor.console.edits import ZoneEditIncidents
from monitor.console.incidents import IncidentSource
from monitor.console.live import LiveRenderer, LiveState, reference_image
from monitor.console.logins import LoginGuard, Throttle
from monitor.console.responses import SECURITY_HEADERS, json_response
from monitor.console.review_api import review_routes
from monitor.console.saves import record_save
from monitor.console.sessions import Sessions, ViewGate
from monitor.console.setup_routes import forbidden, setup_routes
from monitor.console.sources import Source, TrustedProxies, request_source
from monitor.console.zones_api import ZoneEditor
from monitor.errors import ConfigError
from monitor.types import Alert
from monitor.wire.alerts import AlertLimiter

STATIC = Path(__file__).parent / "static"
CHECK_THREADS = 1  # scrypt checks at once (16 MB, ~0.1 s of a core each): a flood of
# guesses takes at most one core from the host the monitor runs on
MAX_WAITING_CHECKS = 32  # more are refused at once (503), never queued without bound
THROTTLE_ALERT = "console_login_throttled"
# uvicorn's options for the console (cli.py and the tests): its proxy_headers would replace the
# socket's peer with an X-Forwarded-For from 127.0.0.1 (its default forwarded_allow_ips), so a
# local process chose its own address; the console reads the header itself, from the proxies of
# --trusted-proxy only (sources.py)
SERVER_OPTIONS = {"proxy_headers": False, "server_header": False}


@dataclass
class Console:
    """Everything the routes need (no globals)."""

    cell_name: str
    live: LiveState
    renderer: LiveRenderer
    editor: ZoneEditor
    incidents: IncidentSource
    operators: Operators
    audit: AuditLog
    references: dict[str, Path]
    edits: ZoneEditIncidents | None = None  # --incidents DIR: each edit is an incident too
    logins: LoginGuard = field(default_factory=LoginGuard)
    on_alert: Callable[[Alert], None] | None = None  # the console's own alerts (lock-outs)
    view_login: bool = False  # viewing needs a login (off loopback): sessions.py
    sessions: Sessions = field(default_factory=Sessions)
    reset_operators: Path | None = None  # the monitor's operators file, shown read-only
    # whose X-Forwarded-For is believed (--trusted-proxy; default none): sources.py
    trusted_proxies: TrustedProxies = field(default_factory=TrustedProxies)
    # the operators' confirm-clear (--reset-key NAME=FILE): None, the console sends none
    confirm: ConfirmClear | None = None


class LoginChecks:
    """Password checks in flight: at most ``CHECK_THREADS`` hashing, ``MAX_WAITING_CHECKS``
    waiting (more are refused at once); the lock-out alerts' rate limit."""

    def __init__(self) -> None:
        self.waiting = 0  # touched on the event loop only
        self._limiter: anyio.CapacityLimiter | None = None
        self.alerts = AlertLimiter()

    def limiter(self) -> anyio.CapacityLimiter:
        if self._limiter is None:  # made inside the running event loop
            self._limiter = anyio.CapacityLimiter(CHECK_THREADS)
        return self._limiter


async def read_body(request: Request) -> bytes:
    """The body, read no further than ``MAX_BODY`` bytes (a larger one is refused, never
    held in memory whole)."""
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > MAX_BODY:
        raise BadRequest(f"the body is {int(declared)} bytes: at most {MAX_BODY}")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > MAX_BODY:
            raise BadRequest(f"the body is over {MAX_BODY} bytes")
        chunks.append(chunk)
    return b"".join(chunks)


def build_app(console: Console) -> Starlette:
    def page(name: str):
        async def handler(request: Request) -> Response:
            return FileResponse(STATIC / name, headers=SECURITY_HEADERS)
        return handler

    async def state(request: Request) -> Response:
        body = console.live.state()
        body["cell"] = console.cell_name
        try:
            file_hash = console.editor.cell().config_hash
        except ConfigError as exc:
            file_hash, body["zone_file_error"] = "", str(exc)
        body["zone_file_hash"] = file_hash
        in_force = body.get("zone_hash") or ""
        # the file on disk and the zone set the monitor decides with: never silently apart
        body["zone_file_pending"] = bool(in_force and file_hash and in_force != file_hash)
        # an edit that weakens protection, waiting for an operator's signed apply
        body["zone_draft"] = console.editor.draft_info()
        body["camera_ids"] = list(console.editor.cell().cameras)
        return json_response(body)

    async def live_jpeg(request: Request) -> Response:
        camera = request.path_params["camera"]
        if camera not in console.editor.cell().cameras:
            return json_response({"error": f"no camera {camera!r}"}, 404)
        data = await run_in_threadpool(console.renderer.jpeg, camera)
        return Response(data, media_type="image/jpeg", headers=SECURITY_HEADERS)

    async def clip(request: Request) -> Response:
        path = console.incidents.clip_path(request.path_params["id"],
                                           request.query_params.get("camera") or None)
        if path is None:
            return json_response({"error": "no clip for this incident"}, 404)
        media = "video/mp4" if path.suffix.lower() in (".mp4", ".m4v") else None
        return FileResponse(path, media_type=media, headers={"cache-control": "no-store"})

    async def thumbnail(request: Request) -> Response:
        data = await run_in_threadpool(console.incidents.thumbnail, request.path_params["id"],
                                       request.query_params.get("camera") or None)
        if data is None:
            return json_response({"error": "no thumbnail for this incident"}, 404)
        return Response(data, media_type="image/jpeg", headers=SECURITY_HEADERS)

    async def zones(request: Request) -> Response:
        try:
            return json_response(console.editor.editor_data())
        except ConfigError as exc:
            return json_response({"error": str(exc)}, 500)

    async def zone_image(request: Request) -> Response:
        camera = request.path_params["camera"]
        cell = console.editor.cell()
        if camera not in cell.cameras:
            return json_response({"error": f"no camera {camera!r}"}, 404)
        img = reference_image(cell, camera, console.references.get(camera))
        _, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 85])
        return Response(buf.tobytes(), media_type="image/jpeg", headers=SECURITY_HEADERS)

    def edit_incident(entry: dict, cause: str = "zone_edit") -> str | None:
        """The audited attempt as a ``zone_edit`` incident (``cause`` ``zone_weakened``: the
        incident of its own of an edit that weakens protection); None: no --incidents, or it
        could not be written: then the audit log says why."""
        if console.edits is None:
            return None
        try:
            return console.edits.record(entry, str(console.live.state().get("state") or ""),
                                        cause)
        except (OSError, sqlite3.Error) as exc:
            console.audit.record(event="zone_edit_incident_error", zone=entry.get("zone"),
                                 operator=entry.get("operator"), result=entry.get("result"),
                                 incident_error=str(exc).splitlines()[0] if str(exc) else
                                 type(exc).__name__)
            return None

    checks = LoginChecks()

    def throttle_alert(throttle: Throttle, source: Source, tried: str) -> None:
        alert = Alert(THROTTLE_ALERT, "warning", f"console: {throttle.message()}", "console",
                      time.time(), details={**source.fields(), "tried": tried[:64]})
        repeat = checks.alerts.admit(alert, time.monotonic())
        if repeat is None:
            return  # held back (a flood of them): counted in the next one's repeat
        alert.details["repeat"] = repeat
        console.audit.record(event="login_throttled", **source.fields(), tried=tried[:64],
                             message=alert.message, repeat=repeat)
        if console.on_alert is not None:
            console.on_alert(alert)

    async def login(source: Source, credentials: tuple[str, str] | None
                    ) -> tuple[str | None, int, str]:
        """(operator, 200, "") for a right password not held back by a delay, else (None,
        status, why)."""
        if not console.operators.enabled:
            return None, 403, "editing is off: the console was started without --passwords"
        if credentials is None:
            return None, 401, "operator name or password not accepted"
        name, password = credentials
        waiting = console.logins.waiting(source.key, name)
        if waiting is not None:
            return None, 429, waiting.message()
        if checks.waiting >= MAX_WAITING_CHECKS:
            return None, 503, "too many password checks at once: try again in a moment"
        checks.waiting += 1
        try:
            # scrypt (~0.1 s of CPU) off the event loop, at most CHECK_THREADS at once, so
            # guessing never slows /api/state
            ok = await anyio.to_thread.run_sync(console.operators.verify, name, password,
                                                limiter=checks.limiter())
        finally:
            checks.waiting -= 1
        if ok:
            # guesses sent at once all pass the check above before any fails: one found right
            # while the others began a delay is refused as they are (no parallel bypass)
            waiting = console.logins.waiting(source.key, name)
            if waiting is not None:
                return None, 429, waiting.message()
            console.logins.succeeded(source.key, name)
            return name, 200, ""
        for throttle in console.logins.failed(source.key, name):
            throttle_alert(throttle, source, name)
        return None, 401, "operator name or password not accepted"

    async def save_zone(request: Request) -> Response:
        zone_id = request.path_params["id"]
        credentials = basic_credentials(request.headers.get("authorization"))
        source = request_source(request, console.trusted_proxies)
        operator, status, why = await login(source, credentials)
        if operator is None:
            # whoever reaches the port: one bounded, rate-limited audit line, never an
            # incident (a flood of them must not push real STOPs out of retention)
            await run_in_threadpool(functools.partial(
                console.audit.refused, zone=zone_id, operator=None,
                tried=credentials[0] if credentials else None, **source.fields(),
                result="refused", error=why))
            headers = {"retry-after": "60"} if status in (429, 503) else {}
            return JSONResponse({"error": why}, status_code=status,
                                headers={**SECURITY_HEADERS, **headers})
        refused = await forbidden(console, operator, "edit_zone", source, zone_id,
                                  SECURITY_HEADERS)
        if refused is not None:
            return refused
        zone = bounded(zone_id, 80)

        def refuse(status: int, result: str, error: str) -> dict:
            """An operator's refused attempt: audited whole (bounded) and an incident."""
            entry = console.audit.record(zone=zone, operator=operator, **source.fields(),
                                         result=result, error=bounded(error, 400),
                                         config_hash_before=current_hash())
            return {"error": error, "incident": edit_incident(entry), "status": status}

        try:
            check_zone_id(zone_id)
            if "json" not in request.headers.get("content-type", ""):
                raise BadRequest("the body must be JSON (content-type: application/json)")
            body = parse_edit_body(await read_body(request))
        except BadRequest as exc:
            out = await run_in_threadpool(refuse, 400, "bad_request", str(exc))
            return json_response(out, out.pop("status"))
        try:
            saved, new = await run_in_threadpool(console.editor.save_polygon, zone_id, body)
        except ConfigError as exc:
            out = await run_in_threadpool(refuse, 422, "invalid", str(exc))
            return json_response(out, out.pop("status"))
        except Exception as exc:  # a fault of ours (disk, a bug): still audited, one line
            text = f"the edit could not be saved: {type(exc).__name__}: " \
                   f"{str(exc).splitlines()[0] if str(exc) else ''}"
            out = await run_in_threadpool(refuse, 500, "error", text)
            return json_response(out, out.pop("status"))
        out = await run_in_threadpool(functools.partial(
            record_save, console, saved, zone_id, operator, source, edit_incident,
            action="added" if new else "changed"))
        # 202: a weakening edit is kept as a draft, in force only after a signed apply
        return json_response(out, 202 if saved.is_draft else 200)

    def current_hash() -> str:
        try:
            return console.editor.cell().config_hash
        except (ConfigError, OSError):
            return ""

    routes = [
        Route("/", page("live.html")),
        Route("/incidents", page("incidents.html")),
        Route("/zones", page("zones.html")),
        Route("/api/state", state),
        Route("/api/live/{camera}.jpg", live_jpeg),
        *review_routes(console, login),
        Route("/api/incidents/{id}/clip", clip),
        Route("/api/incidents/{id}/thumb.jpg", thumbnail),
        Route("/api/zones", zones),
        Route("/api/zones/{camera}/image.jpg", zone_image),
        Route("/api/zones/{id}", save_zone, methods=["PUT"]),
        *setup_routes(console, login, edit_incident, read_body, SECURITY_HEADERS, STATIC),
        *confirm_routes(console, login, read_body, SECURITY_HEADERS),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    return Starlette(routes=routes, middleware=[
        Middleware(ViewGate, required=console.view_login, sessions=console.sessions,
                   operators=console.operators, headers=SECURITY_HEADERS)])
