"""Ed25519 keys and signatures for commands, heartbeats and operator resets.

Why Ed25519 and not HMAC: with HMAC every consumer that can check a command could also forge
one (they share the secret), and every monitor host would hold every operator's secret. With
Ed25519 only the monitor holds the key that signs commands and only each operator holds the
key that signs their resets; controllers and the monitor hold public keys only.

What is signed: the exact payload bytes as they travel (a UTF-8 JSON object), prefixed by a
domain label and the Zenoh key expression, so a signature made for one key (or cell) is never
valid on another::

    message = b"workcell-monitor/1\\n" + key_expr.encode() + b"\\n" + payload

The 64-byte signature travels as the sample's attachment (raw bytes); resets sent as queries
carry it as the query's attachment. Consumers need no canonical JSON: they verify the bytes they
received, then parse them.

Key files: private keys are PKCS#8 PEM written with 0600 permissions; public keys are one line
``ed25519:<base64 of the 32 raw bytes>`` (easy to paste into a controller's config). An
operators file lists ``<operator> ed25519:<base64>`` per line (``#`` starts a comment).

Whoever can write a key or operators file decides whom the monitor or a consumer trusts, so a
file that its group or others may write is refused (a private key also when they may read it),
with the file and its mode in the error. The mode is taken from the opened file (``fstat``),
so a swap between the check and the read cannot slip in another file.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from monitor.errors import ConfigError

DOMAIN = b"workcell-monitor/1\n"
SIGNATURE_BYTES = 64
PUBLIC_PREFIX = "ed25519:"
WRITABLE_BY_OTHERS = 0o022  # group or world write: whoever has it chooses whom we trust


def signed_message(key_expr: str, payload: bytes) -> bytes:
    """The bytes that are signed for ``payload`` published on ``key_expr``."""
    return DOMAIN + key_expr.encode() + b"\n" + payload


@dataclass(frozen=True)
class Signer:
    """Signs payloads with one private key."""

    key: Ed25519PrivateKey

    def sign(self, key_expr: str, payload: bytes) -> bytes:
        return self.key.sign(signed_message(key_expr, payload))

    @property
    def public_text(self) -> str:
        return public_key_text(self.key.public_key())


def verify(public: Ed25519PublicKey, key_expr: str, payload: bytes,
           signature: bytes | None) -> bool:
    """True when ``signature`` is ``public``'s signature of ``payload`` on ``key_expr``."""
    if signature is None or len(signature) != SIGNATURE_BYTES:
        return False
    try:
        public.verify(signature, signed_message(key_expr, payload))
    except InvalidSignature:
        return False
    return True


def public_key_text(public: Ed25519PublicKey) -> str:
    raw = public.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return PUBLIC_PREFIX + base64.b64encode(raw).decode()


def key_fingerprint(text: str) -> str:
    """A short fingerprint of a public key text ``ed25519:<base64>`` (SHA-256 of the text,
    first 16 hex digits): the commissioning report and the console show the same one."""
    return "sha256:" + hashlib.sha256(text.strip().encode()).hexdigest()[:16]


def parse_public_key(text: str, where: str = "public key") -> Ed25519PublicKey:
    """``ed25519:<base64>`` (32 raw bytes) as a public key; ConfigError when it is not one."""
    text = text.strip()
    if not text.startswith(PUBLIC_PREFIX):
        raise ConfigError(f"{where}: not an Ed25519 public key (expected 'ed25519:<base64>')")
    try:
        raw = base64.b64decode(text[len(PUBLIC_PREFIX):], validate=True)
        if len(raw) != 32:
            raise ValueError
        return Ed25519PublicKey.from_public_bytes(raw)
    except (ValueError, binascii.Error):
        raise ConfigError(f"{where}: not an Ed25519 public key (need 32 bytes in base64)"
                          ) from None


def load_public_key(path: str | Path) -> Ed25519PublicKey:
    """A public key file (one line ``ed25519:<base64>``); refused when others can write it."""
    text = _read(path, "public key file", WRITABLE_BY_OTHERS, "chmod 644")
    return parse_public_key(text.split("\n", 1)[0], str(path))


def load_private_key(path: str | Path) -> Signer:
    """A private key file written by ``monitor keys new``; refused when others can read or
    write it."""
    path = Path(path)
    data = _read(path, "private key", 0o077, "chmod 600").encode()
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError):
        raise ConfigError(f"{path}: not an unencrypted PEM private key") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise ConfigError(f"{path}: not an Ed25519 private key")
    return Signer(key)


def load_operators(path: str | Path, what: str = "operators file",
                   who: str = "operator") -> dict[str, Ed25519PublicKey]:
    """An operators file: ``<operator> ed25519:<base64>`` per line; duplicates are refused.
    The selectors file has the same format: ``what``/``who`` name it in the errors."""
    out: dict[str, Ed25519PublicKey] = {}
    text = _read(path, what, WRITABLE_BY_OTHERS, "chmod 644")
    for n, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        where = f"{path}:{n}"
        if len(parts) != 2:
            raise ConfigError(f"{where}: expected '<{who}> ed25519:<base64>'")
        name, key = parts
        if name in out:
            raise ConfigError(f"{where}: {who} {name!r} is listed twice")
        out[name] = parse_public_key(key, where)
    return out


def new_key_pair(private_path: str | Path, force: bool = False) -> tuple[Path, Path, str]:
    """Write a new private key (0600) and its public key (``<private>.pub``); return both paths
    and the public key text. Existing files are never overwritten unless ``force``."""
    private_path = Path(private_path)
    public_path = private_path.with_name(private_path.name + ".pub")
    for p in (private_path, public_path):
        if p.exists() and not force:
            raise ConfigError(f"{p}: exists; not overwriting a key (use --force to replace it)")
    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                            serialization.NoEncryption())
    text = public_key_text(key.public_key())
    try:
        private_path.parent.mkdir(parents=True, exist_ok=True)
        with _open_private(private_path, force) as fh:
            fh.write(pem)
        public_path.write_text(text + "\n", encoding="utf-8")
        os.chmod(public_path, 0o644)  # a umask of 002 would leave it group-writable: refused
    except OSError as exc:
        raise ConfigError(f"{private_path}: cannot write the key: {exc.strerror}") from None
    return private_path, public_path, text


def _open_private(path: Path, force: bool):
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | (0 if force else os.O_EXCL)
    fd = os.open(path, flags, 0o600)
    os.fchmod(fd, 0o600)  # O_CREAT's mode does not apply to an existing file (--force)
    return os.fdopen(fd, "wb")


def _read(path: str | Path, what: str, forbidden: int, fix: str) -> str:
    """The file's text; ConfigError when its mode has any of the ``forbidden`` bits (checked
    on the opened file)."""
    try:
        with open(path, "rb") as fh:
            mode = os.fstat(fh.fileno()).st_mode
            if stat.S_IMODE(mode) & forbidden:
                raise ConfigError(f"{path}: {what} has mode {stat.S_IMODE(mode):04o}: "
                                  f"{_who(stat.S_IMODE(mode) & forbidden)}; refused "
                                  f"({fix} {path})")
            return fh.read().decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such key file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {getattr(exc, 'strerror', None) or exc}"
                          ) from None


def _who(bits: int) -> str:
    """'group and others can write', ... for the offending permission bits."""
    who = " and ".join(w for w, m in (("group", 0o070), ("others", 0o007)) if bits & m)
    can = " and ".join(c for c, m in (("read", 0o044), ("write", 0o022), ("execute", 0o011))
                       if bits & m)
    return f"{who} can {can} it"
