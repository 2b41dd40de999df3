"""Viewing with a login: sessions of the console and the gate in front of its read-only API.

On loopback the pages and every ``GET`` stay open (as before levels). Off loopback (the console
needs TLS and a passwords file there) viewing needs a login of any level too: the live picture
shows the people in the cell and the incidents keep clips of them. Why a session cookie and not
the ``Basic`` header the edits send: a page's ``<img>`` and ``<video>`` cannot send a header,
and a password checked with scrypt (~0.1 s of a core) on every 0.3 s poll would take a core per
viewer. So ``POST /api/login`` checks the password once (the same lock-outs as an edit) and
sets a random token as an ``HttpOnly``, ``SameSite=Strict`` cookie (``Secure`` over TLS): no
script can read it, and no other site's page can make the browser send it.

The session only names the user: the level is read from the passwords file on every request, so
a user removed from the file (or a file broken) is refused at once. Sessions live in memory (a
restart logs everyone out), for ``LIFETIME_S`` at most, ``MAX_PER_USER`` per user at most (that
user's oldest is dropped: one user logging in again and again never logs anyone else out, as a
bound on all sessions once did; the total is bounded by the passwords file's users). Edits never
accept the cookie: each still sends its own ``Basic`` credential, so a forged cross-site request
has nothing to ride on.

A refused view (no session, an expired one, a removed user) answers 401 with one line and is
not audited: a read refused is no change, and a page left open polls several times a second.
"""

from __future__ import annotations

import hashlib
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable

from starlette.requests import Request
from starlette.responses import JSONResponse

from monitor.console.auth import Operators
from monitor.console.levels import may

COOKIE = "workcell_console"
LIFETIME_S = 8 * 3600.0  # a shift
MAX_PER_USER = 16  # sessions of one user (browsers, tabs that logged in anew, machines)
OPEN_PATHS = ("/api/login", "/api/logout", "/api/me")  # answer without a session
VIEW_NEEDS_LOGIN = ("viewing this console needs a login (any level: viewer, operator or "
                    "admin) because it listens off loopback: log in at /setup")


class Sessions:
    """token -> user name, bounded and expiring; ``clock``: monotonic seconds."""

    def __init__(self, clock: Callable[[], float] = time.monotonic,
                 lifetime_s: float = LIFETIME_S, max_per_user: int = MAX_PER_USER) -> None:
        self.clock = clock
        self.lifetime_s = lifetime_s
        self.max_per_user = max_per_user
        # sha256(token) -> (name, expires): the token itself is never kept
        self._open: OrderedDict[bytes, tuple[str, float]] = OrderedDict()
        self._lock = threading.Lock()

    @staticmethod
    def _key(token: str) -> bytes:
        return hashlib.sha256(token.encode()).digest()

    def open(self, name: str) -> str:
        token = secrets.token_urlsafe(32)
        now = self.clock()
        with self._lock:
            for key in [k for k, (_, ends) in self._open.items() if ends <= now]:
                del self._open[key]  # expired ones go first (a login is rare: a scan is cheap)
            mine = [k for k, (who, _) in self._open.items() if who == name]
            for key in mine[:max(0, len(mine) - self.max_per_user + 1)]:
                del self._open[key]  # this user's oldest, never another user's
            self._open[self._key(token)] = (name, now + self.lifetime_s)
        return token

    def name(self, token: str | None) -> str | None:
        """The user of a session that is open, else None."""
        if not token or len(token) > 100:
            return None
        key = self._key(token)
        with self._lock:
            found = self._open.get(key)
            if found is None:
                return None
            if self.clock() >= found[1]:
                del self._open[key]
                return None
            return found[0]

    def close(self, token: str | None) -> None:
        if token:
            with self._lock:
                self._open.pop(self._key(token), None)

    def __len__(self) -> int:
        return len(self._open)


def viewer_of(request: Request, sessions: Sessions, operators: Operators
              ) -> tuple[str | None, str | None]:
    """(name, level) of the request's session as the passwords file says now; (None, None)
    without one, (name, None) for a user no longer in the file."""
    name = sessions.name(request.cookies.get(COOKIE))
    if name is None:
        return None, None
    return name, operators.level(name)


class ViewGate:
    """ASGI middleware: with ``required`` every ``GET``/``HEAD`` of ``/api/`` (but
    ``OPEN_PATHS``) needs a session of a user who may view; pages and static files are open
    (they hold no data)."""

    def __init__(self, app, required: bool, sessions: Sessions, operators: Operators,
                 headers: dict[str, str]) -> None:
        self.app = app
        self.required = required
        self.sessions = sessions
        self.operators = operators
        self.headers = headers

    async def __call__(self, scope, receive, send) -> None:
        if (self.required and scope["type"] == "http" and scope["path"].startswith("/api/")
                and scope["method"] in ("GET", "HEAD") and scope["path"] not in OPEN_PATHS):
            request = Request(scope)
            name, level = viewer_of(request, self.sessions, self.operators)
            if not may(level, "view"):
                why = VIEW_NEEDS_LOGIN if name is None else \
                    f"{name!r} is no longer a user of the passwords file: log in again"
                await JSONResponse({"error": why}, status_code=401,
                                   headers=self.headers)(scope, receive, send)
                return
        await self.app(scope, receive, send)
