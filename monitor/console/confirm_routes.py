"""``POST /api/confirm-clear``: an operator's confirm-clear from the live page, and
``POST /api/reset``: the same operator's plain reset (no look needed: the monitor accepts it
only on its own evidence that the cell is clear, and it drops no hold)
(``confirm_clear.py`` says who may and what the console checks first). Answers 200 with the
monitor's verdict (``accepted`` true or false, its reason: a camera in fault, a person in a
zone, ...), 401/403/429 for a login or level refused, 400 for a bad body, 409 when the console
cannot show the cell, 504 when no monitor answered. Every attempt is one audit line."""

from __future__ import annotations

import functools
from collections.abc import Awaitable, Callable
from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from monitor.console.audit import bounded
from monitor.console.auth import basic_credentials
from monitor.console.confirm_clear import (
    NO_RESET_KEY,
    ConfirmClearRefused,
    missing_pictures,
    parse_request,
)
from monitor.console.setup_routes import forbidden
from monitor.console.sources import Source, request_source

Login = Callable[[Source, tuple[str, str] | None], Awaitable[tuple[str | None, int, str]]]


def confirm_routes(console: Any, login: Login,
                   read_body: Callable[[Request], Awaitable[bytes]],
                   headers: dict) -> list[Route]:
    """The route; ``login`` and ``read_body``: the app's own (one rule for passwords,
    lock-outs and body limits)."""

    async def send(request: Request, confirm: bool) -> Response:
        event = "confirm_clear" if confirm else "reset"
        credentials = basic_credentials(request.headers.get("authorization"))
        source = request_source(request, console.trusted_proxies)
        operator, status, why = await login(source, credentials)
        if operator is None:
            await run_in_threadpool(functools.partial(
                console.audit.refused, event=event, operator=None,
                tried=credentials[0] if credentials else None, **source.fields(),
                result="refused", error=why))
            extra = {"retry-after": "60"} if status in (429, 503) else {}
            return JSONResponse({"error": why}, status_code=status,
                                headers={**headers, **extra})
        refused = await forbidden(console, operator, event, source, "cell", headers)
        if refused is not None:
            return refused
        cameras = list(console.editor.cell().cameras)
        try:
            note, looked = parse_request(await read_body(request), cameras, look=confirm)
            sender = console.confirm
            why = NO_RESET_KEY if sender is None else sender.can(operator)
            if why is not None:
                raise ConfirmClearRefused(why, 403)
            missing = missing_pictures(console.live.preview, cameras) if confirm else []
            if missing:  # the operator cannot have looked at what the console cannot show
                raise ConfirmClearRefused(
                    f"no live picture of {', '.join(missing)} now: the console cannot show "
                    "the cell, so it cannot be confirmed clear here")
            answer = await run_in_threadpool(sender.send, operator, note, confirm)
        except ConfirmClearRefused as exc:
            await run_in_threadpool(functools.partial(
                console.audit.record, event=event, operator=operator, **source.fields(),
                result="refused", error=bounded(str(exc), 400)))
            return JSONResponse({"error": str(exc)}, status_code=exc.status, headers=headers)
        accepted = bool(answer.get("accepted"))
        reason = str(answer.get("reason", ""))
        await run_in_threadpool(functools.partial(
            console.audit.record, event=event, operator=operator, **source.fields(),
            note=bounded(note, 200), looked_at=looked,
            result="accepted" if accepted else "refused_by_monitor",
            reason=bounded(reason, 600), monitor_state=answer.get("state")))
        return JSONResponse({"accepted": accepted, "reason": reason,
                             "state": answer.get("state")}, headers=headers)

    async def confirm_clear(request: Request) -> Response:
        return await send(request, True)

    async def reset(request: Request) -> Response:
        return await send(request, False)

    return [Route("/api/confirm-clear", confirm_clear, methods=["POST"]),
            Route("/api/reset", reset, methods=["POST"])]
