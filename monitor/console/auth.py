"""Who may do what through the console, where it may listen, and the credentials it checks.

Credentials: a name and a password, checked against a passwords file written by ``monitor
console passwd FILE NAME [--level viewer|operator|admin]``: one
``name:level:scrypt$n$r$p$salt$hash`` line per user, mode 0600. A line without a level
(``name:scrypt$...``, the format before levels) is an ``operator``, the rights it had: an
upgrade takes no right away. A level that is not one of ``viewer``, ``operator``, ``admin`` (a
forged or garbled line) stops the console's start with the line's number; a file broken while
the console runs lets nobody in (not even to view where viewing needs a login) until it is
fixed. What each level may do: ``monitor/console/levels.py``.

The browser sends the credentials with each edit (an ``Authorization: Basic`` header set by the
page's script, never remembered by the browser), so a page of another site cannot make the
browser edit a zone. Why passwords rather than the operators' Ed25519 reset keys: a browser
cannot use a key file without an extension or WebCrypto key import, and a key held by the
console server would sign for whoever reaches it. The console never grants a reset by itself:
its reset and confirm-clear are signed with the operator's own key (``--reset-key``) and the
operators file of signed resets stays the one source of truth for who may reset.

Listening: loopback by default; any other address needs TLS (certificate and key) and a
passwords file, or the console refuses to start; there, viewing needs a login too
(``monitor/console/sessions.py``).
"""

from __future__ import annotations

import base64
import binascii
import functools
import hashlib
import hmac
import ipaddress
import os
import re
import secrets
import threading
from dataclasses import dataclass
from pathlib import Path

from monitor.console.levels import DEFAULT_LEVEL, LevelError, parse_level
from monitor.errors import ConfigError

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
_SCRYPT = {"n": 2**14, "r": 8, "p": 1}
MIN_PASSWORD = 8


def hash_password(password: str, salt: bytes | None = None, n: int = _SCRYPT["n"],
                  r: int = _SCRYPT["r"], p: int = _SCRYPT["p"]) -> str:
    salt = salt or secrets.token_bytes(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, n=n, r=r, p=p, dklen=32)
    return f"scrypt${n}${r}${p}${salt.hex()}${digest.hex()}"


def _verify(password: str, stored: str) -> bool:
    try:
        kind, n, r, p, salt, digest = stored.split("$")
        if kind != "scrypt":
            return False
        got = hashlib.scrypt(password.encode(), salt=bytes.fromhex(salt), n=int(n), r=int(r),
                             p=int(p), dklen=len(digest) // 2)
    except (ValueError, MemoryError):
        return False
    return hmac.compare_digest(got.hex(), digest)


@dataclass(frozen=True)
class Entry:
    """One user of the passwords file: the level and the stored scrypt hash."""

    level: str
    stored: str


def read_entries(path: str | Path) -> dict[str, Entry]:
    """name -> Entry; ConfigError (one line naming the line) on a bad file."""
    p = Path(path)
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise ConfigError(f"{p}: passwords file not found (make one: monitor console passwd "
                          f"{p} NAME --level admin)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read the passwords file: {exc}") from None
    out: dict[str, Entry] = {}
    for k, line in enumerate(lines, 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        name, sep, rest = line.strip().partition(":")
        level = DEFAULT_LEVEL  # the format before levels: an operator, as it was
        if sep and not rest.startswith("scrypt$"):
            text, sep, rest = rest.partition(":")
            try:
                level = parse_level(text)
            except LevelError as exc:
                raise ConfigError(f"{p}:{k}: {exc}") from None
        if not sep or not _NAME.match(name) or not rest.startswith("scrypt$"):
            raise ConfigError(f"{p}:{k}: not a 'name:level:scrypt$...' line")
        if name in out:
            raise ConfigError(f"{p}:{k}: {name!r} is listed twice")
        out[name] = Entry(level, rest)
    return out


def read_passwords(path: str | Path) -> dict[str, str]:
    """name -> stored hash; ConfigError (one line) on a bad file."""
    return {name: e.stored for name, e in read_entries(path).items()}


def set_password(path: str | Path, operator: str, password: str,
                 level: str | None = None) -> str:
    """Add or replace one user's line (file mode 0600, written atomically); ``level`` None
    keeps the user's level (a new user: operator). Every line is written with its level.
    Returns the level written."""
    if not _NAME.match(operator):
        raise ConfigError(f"name {operator!r}: letters, digits, _ . - only")
    if len(password) < MIN_PASSWORD:
        raise ConfigError(f"password too short: at least {MIN_PASSWORD} characters")
    try:
        level = parse_level(level) if level is not None else None
    except LevelError as exc:
        raise ConfigError(str(exc)) from None
    p = Path(path)
    entries = read_entries(p) if p.exists() else {}
    old = entries.get(operator)
    level = level or (old.level if old else DEFAULT_LEVEL)
    entries[operator] = Entry(level, hash_password(password))
    text = "".join(f"{name}:{e.level}:{e.stored}\n" for name, e in entries.items())
    tmp = p.with_name(f".{p.name}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, p)
    finally:
        tmp.unlink(missing_ok=True)
    return level


class Operators:
    """Checks the Basic credentials of a request against the passwords file (re-read when it
    changes, so a revoked operator is refused without a restart)."""

    def __init__(self, path: str | Path | None) -> None:
        self.path = Path(path) if path is not None else None
        self._cache: tuple[float, dict[str, Entry]] = (-1.0, {})
        self._lock = threading.Lock()
        if self.path is not None:
            read_entries(self.path)  # a bad file stops the start, with its line

    @property
    def enabled(self) -> bool:
        return self.path is not None

    def _entries(self) -> dict[str, Entry]:
        if self.path is None:
            return {}
        try:
            mtime = self.path.stat().st_mtime
        except OSError:
            return {}  # removed: nobody may edit
        with self._lock:
            if mtime != self._cache[0]:
                try:
                    self._cache = (mtime, read_entries(self.path))
                except ConfigError:
                    self._cache = (mtime, {})  # broken: nobody may edit
            return self._cache[1]

    def verify(self, name: str, password: str) -> bool:
        """Whether ``password`` is ``name``'s. Blocking (scrypt, ~0.1 s): call it off the
        event loop."""
        if self.path is None or not _NAME.match(name):
            return False  # not a name an operator can have: no hash to compare with
        entry = self._entries().get(name)
        # an unknown name costs the same scrypt as a known one (no probing of names)
        ok = _verify(password, entry.stored if entry else _dummy_hash())
        return ok and entry is not None

    def level(self, name: str) -> str | None:
        """``name``'s level in the file as it is now (None: not in it, or the file is
        broken or gone: that user may do nothing)."""
        entry = self._entries().get(name)
        return entry.level if entry else None

    def check(self, authorization: str | None) -> str | None:
        """The operator named by a valid ``Basic`` header, else None (blocking, as
        ``verify``)."""
        credentials = basic_credentials(authorization) if self.path is not None else None
        if credentials is None:
            return None
        return credentials[0] if self.verify(*credentials) else None


def basic_credentials(authorization: str | None) -> tuple[str, str] | None:
    """(name, password) of a ``Basic`` header, None when there is none or it is malformed."""
    if not authorization:
        return None
    scheme, _, blob = authorization.partition(" ")
    if scheme.lower() != "basic":
        return None
    try:
        name, sep, password = base64.b64decode(blob.strip(), validate=True).decode(
            "utf-8").partition(":")
    except (binascii.Error, UnicodeDecodeError):
        return None
    return (name, password) if sep else None


@functools.cache
def _dummy_hash() -> str:
    return hash_password("", salt=b"\0" * 16)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def require_safe_listen(host: str, tls: bool, operators: bool) -> None:
    """Off loopback the console needs TLS and operator passwords; refused otherwise."""
    if is_loopback(host):
        return
    # --https-*, not --tls-*: the console's --tls-cert/--tls-key are its Zenoh link's
    missing = [what for what, ok in (("TLS (--https-cert and --https-key)", tls),
                                      ("operator passwords (--passwords)", operators)) if not ok]
    if missing:
        raise ConfigError(f"monitor console: listening on {host} (not loopback) needs "
                          f"{' and '.join(missing)}; or listen on 127.0.0.1")
