"""One bounded JSON decoder for everything that arrives over the bus: holds, commands, resets,
mutes, zone applies, zone set selections (and the operator names their refusals quote).

``json.loads`` alone trusts its input more than a bus may: 10,000 ``[`` raise a RecursionError,
``1e400`` reads as infinity, ``10**400`` as an int no float holds (an OverflowError later, in
whatever arithmetic touches it), ``NaN`` as a float that fails every comparison. Each parser
guarded some of these; ``load`` guards all of them before any field is read, and says which
one in its ``PayloadError`` (a ValueError), so a caller refuses the message as invalid with a
reason instead of letting an exception escape its handler.

The bytes are decoded to text first (UTF-8, or the UTF-16/32 that ``json.loads`` also reads,
told apart as it does by ``json.detect_encoding``) and every bound is checked on that text:
the nesting check once scanned the raw bytes for ``[`` and ``{``, so UTF-16 bytes (each bracket
followed by a zero byte, a zero byte that broke the string pattern) passed it nested 985 levels
deep (issue 48); every parser after it then refused them cleanly, but only by luck.

Pure functions, no imports from the project (bottom layer).
"""

from __future__ import annotations

import json
import re

MAX_DEPTH = 16  # the deepest bus payload (holds: body / entries / entry / box) has 4 levels
MAX_NUMBER_CHARS = 32  # a wall time, a seq, a nanosecond stamp: all far shorter
MAX_MAGNITUDE = 2.0**63  # |x| of any number (ns since the epoch fit; 1e400 and 10**400 do not)

# the tokens that matter for depth: strings (skipped whole, escapes included) and brackets
_DEPTH_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]')
_OPEN = frozenset("[{")


class PayloadError(ValueError):
    """A bus payload refused before any field was read; the message is the one-line reason."""


def _bounded(text: str, value: float | int) -> float | int:
    if isinstance(value, float) and value != value:  # NaN spelled as a number (never JSON)
        raise PayloadError(f"number {text[:40]} is not a number")
    if not abs(value) <= MAX_MAGNITUDE:  # also refuses inf (1e400)
        raise PayloadError(f"number {text[:40]} is out of range (|x| <= 2**63)")
    return value


def _parse_int(text: str) -> int:
    if len(text) > MAX_NUMBER_CHARS:
        raise PayloadError(f"a number has {len(text)} digits (at most {MAX_NUMBER_CHARS})")
    return int(_bounded(text, int(text)))


def _parse_float(text: str) -> float:
    if len(text) > MAX_NUMBER_CHARS:
        raise PayloadError(f"a number has {len(text)} characters (at most {MAX_NUMBER_CHARS})")
    return float(_bounded(text, float(text)))


def _no_constant(name: str) -> float:
    raise PayloadError(f"{name} is not a number a bus message may hold")


def check_depth(payload: bytes | str, max_depth: int = MAX_DEPTH) -> None:
    """Refuse nesting deeper than ``max_depth`` (brackets inside strings do not count);
    ``payload`` is the text, or bytes that are decoded first (``decode``)."""
    text = payload if isinstance(payload, str) else decode(payload)
    if text.count("[") + text.count("{") <= max_depth:
        return  # too few brackets to nest that deep: no scan needed
    depth = 0
    for m in _DEPTH_TOKENS.finditer(text):
        c = m.group()[0]
        if c in _OPEN:
            depth += 1
            if depth > max_depth:
                raise PayloadError(f"nested deeper than {max_depth} levels")
        elif c != '"':  # a closing bracket ('"' starts a skipped string)
            depth -= 1


def decode(raw: bytes) -> str:
    """The text of a JSON payload in any encoding JSON allows (UTF-8 with or without a BOM,
    UTF-16 or UTF-32), as ``json.loads`` would read it. PayloadError when it is none."""
    encoding = json.detect_encoding(raw)
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError:
        raise PayloadError(f"payload is not {encoding.upper().replace('-SIG', '')} "
                           "text") from None


def load(payload: bytes | bytearray | memoryview, max_bytes: int,
         max_depth: int = MAX_DEPTH) -> object:
    """The JSON value of ``payload``, bounded: at most ``max_bytes`` bytes of JSON text (UTF-8,
    or UTF-16/32), nesting at most ``max_depth`` (counted on the decoded text), numbers of at
    most ``MAX_NUMBER_CHARS`` characters and magnitude ``MAX_MAGNITUDE``, no NaN or Infinity.
    Raises ``PayloadError`` naming the first fault."""
    if not isinstance(payload, bytes | bytearray | memoryview):
        raise PayloadError(f"payload is a {type(payload).__name__}, not bytes")
    raw = bytes(payload)
    if len(raw) > max_bytes:
        raise PayloadError(f"payload has {len(raw)} bytes (at most {max_bytes})")
    text = decode(raw)  # every bound below holds on what json reads, whatever the encoding
    check_depth(text, max_depth)
    try:
        return json.loads(text, parse_int=_parse_int, parse_float=_parse_float,
                          parse_constant=_no_constant)
    except PayloadError:
        raise
    except (ValueError, RecursionError):  # RecursionError: unreachable after check_depth
        raise PayloadError("payload is not JSON") from None


def load_object(payload: bytes | bytearray | memoryview, max_bytes: int,
                max_depth: int = MAX_DEPTH) -> dict:
    """``load``, and the value must be a JSON object."""
    body = load(payload, max_bytes, max_depth)
    if not isinstance(body, dict):
        raise PayloadError(f"payload is a JSON {type(body).__name__}, not an object")
    return body
