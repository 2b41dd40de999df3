"""The users file of `monitor bridge opcua --users FILE`: names and salted password hashes.

One user a line, ``NAME:pbkdf2-sha256:ITERATIONS:SALT_HEX:HASH_HEX``; ``#`` starts a comment.
Passwords are never stored: a stolen file gives an attacker PBKDF2 work per guess, not the
passwords (which people reuse). Make a line with::

    python -m monitor.adapters.opcua_users NAME      # reads the password from stdin

Every user is read-only, like an anonymous client (docs/opcua.md): the user list decides who
may READ the safety state when anonymous access is switched off.
"""

from __future__ import annotations

import getpass
import hashlib
import hmac
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from monitor.errors import ConfigError

SCHEME = "pbkdf2-sha256"
DEFAULT_ITERATIONS = 600_000  # OWASP's figure for PBKDF2-HMAC-SHA256
_NAME = re.compile(r"^[A-Za-z0-9_.@-]{1,64}$")


@dataclass(frozen=True)
class PasswordHash:
    iterations: int
    salt: bytes
    digest: bytes

    def matches(self, password: str) -> bool:
        got = hashlib.pbkdf2_hmac("sha256", password.encode(), self.salt, self.iterations)
        return hmac.compare_digest(got, self.digest)


def user_line(name: str, password: str, iterations: int = DEFAULT_ITERATIONS) -> str:
    """The users file line for ``name`` with ``password`` (a fresh random salt)."""
    if not _NAME.match(name):
        raise ConfigError(f"user name {name!r}: use 1-64 letters, digits, '_', '.', '@', '-'")
    if not password:
        raise ConfigError(f"user {name}: empty password")
    salt = os.urandom(16)
    digest = hashlib.pbkdf2_hmac("sha256", password.encode(), salt, iterations)
    return f"{name}:{SCHEME}:{iterations}:{salt.hex()}:{digest.hex()}"


def load_users(path: str | Path) -> dict[str, PasswordHash]:
    """The users of ``path``; a ConfigError naming the file and line for anything malformed."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"OPC UA users file {path}: cannot read it ({exc})") from None
    users: dict[str, PasswordHash] = {}
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = f"OPC UA users file {path} line {number}"
        parts = line.split(":")
        if len(parts) != 5 or parts[1] != SCHEME:
            raise ConfigError(f"{where}: expected NAME:{SCHEME}:ITERATIONS:SALT_HEX:HASH_HEX "
                              "(make lines with `python -m monitor.adapters.opcua_users NAME`)")
        name, _, iterations, salt, digest = parts
        if not _NAME.match(name):
            raise ConfigError(f"{where}: bad user name {name!r}")
        if name in users:
            raise ConfigError(f"{where}: user {name} appears twice")
        try:
            h = PasswordHash(int(iterations), bytes.fromhex(salt), bytes.fromhex(digest))
        except ValueError:
            raise ConfigError(f"{where}: ITERATIONS must be an integer, SALT and HASH hex"
                              ) from None
        if h.iterations < 1000 or len(h.salt) < 8 or len(h.digest) != 32:
            raise ConfigError(f"{where}: need >= 1000 iterations, a salt of >= 8 bytes and a "
                              "32-byte SHA-256 hash")
        users[name] = h
    if not users:
        raise ConfigError(f"OPC UA users file {path}: no users in it")
    return users


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m monitor.adapters.opcua_users NAME  (password from stdin)",
              file=sys.stderr)
        return 2
    password = (getpass.getpass(f"password for {args[0]}: ") if sys.stdin.isatty()
                else sys.stdin.readline().rstrip("\n"))
    try:
        print(user_line(args[0], password))
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
