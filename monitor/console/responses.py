"""The headers every console answer carries, and its JSON answer."""

from __future__ import annotations

from starlette.responses import JSONResponse

SECURITY_HEADERS = {
    "cache-control": "no-store",
    "x-content-type-options": "nosniff",
    "x-frame-options": "DENY",
    # only the console's own scripts and styles: no inline script or style, nothing fetched
    # from elsewhere
    "content-security-policy": "default-src 'self'; img-src 'self' blob:; media-src 'self'; "
                               "object-src 'none'; frame-ancestors 'none'",
    "referrer-policy": "no-referrer",
}


def json_response(body: object, status: int = 200,
                  headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse(body, status_code=status, headers={**SECURITY_HEADERS,
                                                           **(headers or {})})
