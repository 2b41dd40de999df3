"""Who may reset, as the console shows it: the monitor's operators file, read-only.

The console grants no reset (``monitor/console/levels.py``): a reset is a signed request of an
operator listed in the monitor's operators file (``bus.operators_file``, ``<name>
ed25519:<base64>`` per line, docs/security.md). So that there is one source of truth, the setup
page lists that file's names and key fingerprints (the commissioning report's fingerprint,
``monitor.wire.signing.key_fingerprint``), read with the monitor's own reader
(``monitor.wire.signing.load_operators``: a file that group or others may write is refused there as
it is by the monitor). It is read again on every request: what the page shows is the file now
(the running monitor reads it at start: a changed file takes effect when the monitor restarts).
"""

from __future__ import annotations

from pathlib import Path

from monitor.errors import ConfigError
from monitor.wire.signing import key_fingerprint, load_operators, public_key_text


def reset_operators(path: Path | None) -> dict:
    """``{"file", "operators": [{"name", "fingerprint"}], "error"}``; the error is one line
    (no file given, unreadable, refused mode, a bad line) and then the list is empty."""
    if path is None:
        return {"file": None, "operators": [],
                "error": "not shown: start the console with --operators FILE (the monitor's "
                         "bus.operators_file) to list who may reset"}
    try:
        keys = load_operators(path)
    except ConfigError as exc:
        return {"file": str(path), "operators": [], "error": str(exc)}
    return {"file": str(path), "error": None,
            "operators": [{"name": name, "fingerprint": key_fingerprint(public_key_text(key))}
                          for name, key in sorted(keys.items())]}
