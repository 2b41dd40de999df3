"""Signed evidence files: the commissioning report and the commissioned record, signed over every
byte with the commissioner's Ed25519 key.

A signed file is ``body + key_open + KEY + mid + SIGNATURE + tail``: ``KEY`` is the signer's
public key text (``ed25519:<base64>``, always 52 characters), ``SIGNATURE`` the 64-byte
signature in base64 (always 88 characters), and ``key_open``, ``mid`` and ``tail`` are fixed
strings of the file's format (``Layout``). The signature block is therefore found by exact
position from the end of the file, never by searching for a pattern: the signed message is the
whole file with only those 88 characters taken out, so adding, removing or changing any other
byte (a line anywhere, an extra ``<style>``, a second "signature" line, a byte after the end)
fails the check. The signer's key is inside the signed bytes: swapping it breaks the signature,
and re-signing with another key names that other key (whoever checks compares it with the
commissioners file, or ``--key``).

The message is prefixed like every other signature of the project (``signing.signed_message``)
with a purpose (``commissioning-report``, ``commissioned-record``), so a report's signature is
never valid as a record's, nor a command's as either.
"""

from __future__ import annotations

import base64
import binascii
from dataclasses import dataclass

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from monitor.errors import ConfigError
from monitor.wire.signing import (
    PUBLIC_PREFIX,
    SIGNATURE_BYTES,
    Signer,
    parse_public_key,
    verify,
)

KEY_CHARS = len(PUBLIC_PREFIX) + 44  # "ed25519:" + base64 of 32 bytes
SIGNATURE_CHARS = 88  # base64 of 64 bytes


@dataclass(frozen=True)
class Layout:
    """The fixed strings around the key and the signature of one file format."""

    purpose: str  # what the signature is for (part of the signed message)
    key_open: bytes
    mid: bytes
    tail: bytes

    @property
    def block_length(self) -> int:
        return len(self.key_open) + KEY_CHARS + len(self.mid) + SIGNATURE_CHARS + len(self.tail)


@dataclass(frozen=True)
class Opened:
    """A signed file taken apart: ``valid`` is whether ``signature`` is ``key``'s over the
    file's every other byte."""

    body: bytes  # everything before the signature block
    key_text: str
    key: Ed25519PublicKey
    valid: bool


class NotSigned(ValueError):
    """The file does not end in the format's signature block (not signed, or cut)."""


def sign(body: bytes, layout: Layout, signer: Signer) -> bytes:
    """``body`` with its signature block."""
    key = signer.public_text.encode()
    assert len(key) == KEY_CHARS
    unsigned = body + layout.key_open + key + layout.mid + layout.tail
    signature = base64.b64encode(signer.sign(layout.purpose, unsigned))
    assert len(signature) == SIGNATURE_CHARS
    return body + layout.key_open + key + layout.mid + signature + layout.tail


def open_signed(data: bytes, layout: Layout) -> Opened:
    """Take a signed file apart by position and check its signature; ``NotSigned`` when its
    end is not the format's signature block."""
    if len(data) < layout.block_length or not data.endswith(layout.tail):
        raise NotSigned("no signature block at the end of the file")
    end_sig = len(data) - len(layout.tail)
    start_sig = end_sig - SIGNATURE_CHARS
    end_key = start_sig - len(layout.mid)
    start_key = end_key - KEY_CHARS
    body_end = start_key - len(layout.key_open)
    if data[end_key:start_sig] != layout.mid or data[body_end:start_key] != layout.key_open:
        raise NotSigned("the signature block is not where the format puts it")
    try:
        key_text = data[start_key:end_key].decode("ascii")
        key = parse_public_key(key_text, "the signer's key")
        signature = base64.b64decode(data[start_sig:end_sig], validate=True)
    except (UnicodeDecodeError, binascii.Error, ValueError, ConfigError) as exc:
        raise NotSigned(f"the signature block is malformed ({exc})") from None
    if len(signature) != SIGNATURE_BYTES:
        raise NotSigned("the signature block is malformed (not 64 bytes)")
    unsigned = data[:start_sig] + data[end_sig:]
    return Opened(data[:body_end], key_text, key, verify(key, layout.purpose, unsigned,
                                                         signature))
