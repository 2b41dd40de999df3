"""The routes of user levels and of the setup page (``/setup``), added to the console's app by
``build_app``; the rules they follow are ``levels.py`` (who may do what), ``sessions.py`` (a
login for viewing), ``resetters.py`` (who may reset: the operators file) and ``setup_api.py``
(the edits).

``POST /api/login`` (``Basic`` credential; a session cookie), ``POST /api/logout``,
``GET /api/me`` (who the session is, its level and rights), ``GET /api/access`` (the rights of
each level and who may reset), ``GET /api/setup`` (zone sets, rules, mutes, volumes);
``PUT /api/setup/mute/{zone}``, ``PUT /api/setup/rules``, ``PUT /api/setup/volume/{zone}``
(an admin's ``Basic`` credential on each request, as the zone editor's saves).

Every edit attempt is audited like a zone edit (``event: zone_edit`` with ``edit``: mute, rules,
volume): refused credentials as bounded, rate-limited lines; a user whose password was accepted
but whose level is too low gets a 403 whose one line names the level needed, audited whole
(``result: forbidden``, with the level), never an incident (it changed nothing); any other
attempt by an admin is audited whole and is a ``zone_edit`` incident, as the zone editor's.
"""

from __future__ import annotations

import functools
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Route

from monitor.console.audit import bounded
from monitor.console.auth import basic_credentials
from monitor.console.edit_body import BadRequest, check_zone_id, parse_edit_body
from monitor.console.levels import LEVELS, may, refusal, table
from monitor.console.resetters import reset_operators
from monitor.console.saves import record_save
from monitor.console.sessions import COOKIE, LIFETIME_S, viewer_of
from monitor.console.setup_api import (
    MUTE_FIELDS,
    RULES_FIELDS,
    TEXT,
    VOLUME_FIELDS,
    SetupEditor,
)
from monitor.console.sources import Source, request_source
from monitor.errors import ConfigError

Login = Callable[[Source, "tuple[str, str] | None"], Awaitable[tuple[str | None, int, str]]]
NOTE = ("a draft: the running monitor keeps its zone set until an operator applies the file "
        "(monitor zones apply, signed; its commands name the hash in force)")


async def forbidden(console: Any, name: str, action: str, source: Source, target: str,
                    headers: dict) -> Response | None:
    """A 403 (audited whole, one line naming the level needed) when ``name``'s level, as the
    passwords file says now, may not do ``action``; None when it may."""
    level = console.operators.level(name)
    why = refusal(name, level, action)
    if why is None:
        return None
    await run_in_threadpool(functools.partial(
        console.audit.record, zone=bounded(target, 80), operator=name, level=level,
        **source.fields(), result="forbidden", edit=action, error=why))
    return JSONResponse({"error": why}, status_code=403, headers=headers)


def setup_routes(console: Any, login: Login, edit_incident: Callable[..., str | None],
                 read_body: Callable[[Request], Awaitable[bytes]], headers: dict,
                 static: Path) -> list[Route]:
    """The routes; ``login``, ``edit_incident``, ``read_body``: the app's own (one rule for
    passwords and lock-outs, incidents and body limits)."""
    setup = SetupEditor(console.editor)

    def current_hash() -> str:
        try:
            return console.editor.cell().config_hash
        except (ConfigError, OSError):
            return ""

    async def credentialed(request: Request, target: str) -> tuple[str | None, Response | None]:
        """The user of the request's ``Basic`` credential, or the refusal to answer."""
        credentials = basic_credentials(request.headers.get("authorization"))
        source = request_source(request, console.trusted_proxies)
        name, status, why = await login(source, credentials)
        if name is not None:
            return name, None
        await run_in_threadpool(functools.partial(
            console.audit.refused, zone=target, operator=None,
            tried=credentials[0] if credentials else None, **source.fields(), result="refused",
            error=why))
        extra = {"retry-after": "60"} if status in (429, 503) else {}
        return None, JSONResponse({"error": why}, status_code=status,
                                  headers={**headers, **extra})

    async def edit(request: Request, action: str, target: str, fields: tuple[str, ...],
                   run: Callable[[dict], Any], zone_id: bool = True) -> Response:
        name, refused = await credentialed(request, target)
        if refused is not None:
            return refused
        source = request_source(request, console.trusted_proxies)
        refused = await forbidden(console, name, action, source, target, headers)
        if refused is not None:
            return refused

        def refuse(status: int, result: str, error: str) -> Response:
            entry = console.audit.record(zone=bounded(target, 80), operator=name,
                                         **source.fields(), edit=action, result=result,
                                         error=bounded(error, 400),
                                         config_hash_before=current_hash())
            return JSONResponse({"error": error, "incident": edit_incident(entry)},
                                status_code=status, headers=headers)

        try:
            if zone_id:
                check_zone_id(target)
            if "json" not in request.headers.get("content-type", ""):
                raise BadRequest("the body must be JSON (content-type: application/json)")
            body = parse_edit_body(await read_body(request), fields, TEXT)
        except BadRequest as exc:
            return await run_in_threadpool(refuse, 400, "bad_request", str(exc))
        try:
            saved = await run_in_threadpool(run, body)
        except BadRequest as exc:
            return await run_in_threadpool(refuse, 400, "bad_request", str(exc))
        except ConfigError as exc:
            return await run_in_threadpool(refuse, 422, "invalid", str(exc))
        except Exception as exc:  # a fault of ours (disk, a bug): still audited, one line
            text = f"the edit could not be saved: {type(exc).__name__}: " \
                   f"{str(exc).splitlines()[0] if str(exc) else ''}"
            return await run_in_threadpool(refuse, 500, "error", text)
        out = await run_in_threadpool(functools.partial(
            record_save, console, saved, target, name, source, edit_incident, edit=action,
            action="changed"))
        if not saved.is_draft:
            out["note"] = NOTE
        return JSONResponse(out, status_code=202 if saved.is_draft else 200, headers=headers)

    async def save_mute(request: Request) -> Response:
        zone = request.path_params["zone"]
        return await edit(request, "edit_mute", zone, MUTE_FIELDS,
                          lambda body: setup.save_mute(zone, body))

    async def save_rules(request: Request) -> Response:
        return await edit(request, "edit_sets", "(zone set rules)", RULES_FIELDS,
                          setup.save_rules, zone_id=False)

    async def save_volume(request: Request) -> Response:
        zone = request.path_params["zone"]
        return await edit(request, "edit_volume", zone, VOLUME_FIELDS,
                          lambda body: setup.save_box(zone, body))

    async def login_route(request: Request) -> Response:
        name, refused = await credentialed(request, "(login)")
        if refused is not None:
            return refused
        level = console.operators.level(name)
        token = console.sessions.open(name)
        await run_in_threadpool(functools.partial(
            console.audit.record, event="login", operator=name, level=level,
            **request_source(request, console.trusted_proxies).fields(), result="ok"))
        response = JSONResponse({"name": name, "level": level}, headers=headers)
        response.set_cookie(COOKIE, token, max_age=int(LIFETIME_S), path="/", httponly=True,
                            samesite="strict", secure=request.url.scheme == "https")
        return response

    async def logout(request: Request) -> Response:
        console.sessions.close(request.cookies.get(COOKIE))
        response = JSONResponse({"name": None}, headers=headers)
        response.delete_cookie(COOKIE, path="/")
        return response

    async def me(request: Request) -> Response:
        name, level = viewer_of(request, console.sessions, console.operators)
        return JSONResponse({"name": name, "level": level, "view_login": console.view_login,
                             "passwords": console.operators.enabled,
                             "may": {row["action"]: may(level, row["action"])
                                     for row in table()}}, headers=headers)

    async def access(request: Request) -> Response:
        body = await run_in_threadpool(reset_operators, console.reset_operators)
        return JSONResponse({"levels": list(LEVELS), "rights": table(), "reset": body},
                            headers=headers)

    async def setup_data(request: Request) -> Response:
        try:
            return JSONResponse(await run_in_threadpool(setup.data), headers=headers)
        except ConfigError as exc:
            return JSONResponse({"error": str(exc)}, status_code=500, headers=headers)

    async def page(request: Request) -> Response:
        return FileResponse(static / "setup.html", headers=headers)

    return [
        Route("/setup", page),
        Route("/api/login", login_route, methods=["POST"]),
        Route("/api/logout", logout, methods=["POST"]),
        Route("/api/me", me),
        Route("/api/access", access),
        Route("/api/setup", setup_data),
        Route("/api/setup/mute/{zone}", save_mute, methods=["PUT"]),
        Route("/api/setup/rules", save_rules, methods=["PUT"]),
        Route("/api/setup/volume/{zone}", save_volume, methods=["PUT"]),
    ]

