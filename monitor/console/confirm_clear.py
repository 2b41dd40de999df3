"""Confirm-clear from the console: an operator who has looked at the fresh live picture of
every camera (the lost persons' areas and the unseen foot positions drawn over it) confirms
the cell clear, in one step.

Who may: a console user at the ``operator`` level (``levels.py``) for whom the console holds
that operator's own reset key (``--reset-key NAME=FILE``, the private key whose public half the
monitor's operators file lists under NAME). The console signs the same request
``monitor reset --confirm-clear`` sends (``monitor.wire.resets.reset_payload``: the monitor's
boot and latch nonce read from its status, ``confirm_clear`` set); the monitor judges it as any
other: it verifies the signature against its operators file, refuses it while a camera is in
fault or a person is seen in a zone, and drops the lost persons' holds and accepts the reset in
the same step when it may. The level alone grants nothing the operators file does not.

The same operator may send a plain reset with the same key (``send(..., confirm_clear=False)``,
``POST /api/reset``): strictly less than a confirm-clear, since the monitor accepts it only when
it sees the cell clear itself and it drops no hold. The live page offers the plain reset while
the monitor is latched and the confirm-clear only while a lost person's area holds a zone
(also one in a hidden pocket: a pocket holds only through the areas that reach it): a
confirm-clear as the only button is pressed by habit and empties the restart interlock.

The console refuses before signing when it cannot show the cell: a camera of the zone file
without a live picture now (``LiveState.preview``: signed, captured within ``LIVE_WITHIN_S``),
or a request that does not say it was shown every camera. Every attempt, refused or sent, is
one line of the console's audit log (``event = confirm_clear``) with the monitor's answer.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from monitor.bus.session import BusKeys
from monitor.cli.operator import first_status
from monitor.errors import ConfigError
from monitor.wire.answers import ignored_text
from monitor.wire.resets import latch_of_status, request_reset, reset_payload
from monitor.wire.signing import Signer, load_private_key

MAX_NOTE = 200  # characters of the operator's note
NO_RESET_KEY = ("the console holds no reset key: start it with --reset-key NAME=FILE (an operator "
                "of the monitor's operators file), or use monitor reset --confirm-clear")


class ConfirmClearRefused(Exception):
    """The console does not send the confirm-clear; the message says why (one line)."""

    def __init__(self, message: str, status: int = 409) -> None:
        super().__init__(message)
        self.status = status


def reset_keys(items: list[str]) -> dict[str, Signer]:
    """``--reset-key NAME=FILE`` items as NAME -> that operator's signer (one line on a bad
    item or key file)."""
    out: dict[str, Signer] = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise ConfigError(f"--reset-key {item!r}: expected NAME=FILE (an operator of the "
                              "monitor's operators file and their private key)")
        if name in out:
            raise ConfigError(f"--reset-key: {name!r} given twice")
        out[name] = load_private_key(Path(path))
    return out


def parse_request(raw: bytes, cameras: list[str],
                  look: bool = True) -> tuple[str, list[str]]:
    """(note, cameras shown) of a confirm-clear body ``{"note": str, "looked_at": [camera
    ids]}``; a body that is not that, or does not name every camera of the cell, is refused
    (400): the operator confirms what they were shown. ``look`` False (a plain reset, which
    the monitor judges on its own evidence): ``looked_at`` may be left out."""
    try:
        body = json.loads(raw or b"{}")
    except (ValueError, UnicodeDecodeError, RecursionError):
        raise ConfirmClearRefused("the body is not JSON", 400) from None
    if not isinstance(body, dict):
        raise ConfirmClearRefused("the body must be a JSON object", 400)
    note = body.get("note", "")
    looked = body.get("looked_at", None if look else [])
    if not isinstance(note, str) or len(note) > MAX_NOTE:
        raise ConfirmClearRefused(f"note: a text of at most {MAX_NOTE} characters", 400)
    if not isinstance(looked, list) or not all(isinstance(c, str) for c in looked):
        raise ConfirmClearRefused("looked_at: the camera ids whose live pictures were shown",
                                  400)
    unseen = [c for c in cameras if c not in looked]
    if look and unseen:
        raise ConfirmClearRefused(f"the live picture of {', '.join(unseen)} was not shown: "
                                  "confirm the cell clear only after looking at every camera",
                                  400)
    return note, looked


def missing_pictures(preview: Callable[[str], tuple[bytes | None, float | None]],
                     cameras: list[str]) -> list[str]:
    """The cameras without a live picture now (``preview(camera)`` gives none)."""
    return [c for c in cameras if preview(c)[0] is None]


@dataclass
class ConfirmClear:
    """Signs and sends the confirm-clear of a console operator; the monitor's answer."""

    session: object  # the console's Zenoh session
    keys: BusKeys
    signers: dict[str, Signer]
    cell: str = ""  # the cell named in the request (as `monitor reset` names it)
    monitor_keys: tuple | None = None  # only an answer signed by one of them counts
    timeout_s: float = 5.0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def can(self, operator: str) -> str | None:
        """Why ``operator``'s confirm-clear cannot be signed here; None when it can."""
        if operator in self.signers:
            return None
        if not self.signers:
            return NO_RESET_KEY
        return (f"the console holds no reset key for {operator!r} (--reset-key "
                f"{operator}=FILE): use monitor reset --confirm-clear")

    def send(self, operator: str, note: str, confirm_clear: bool = True) -> dict:
        """The monitor's answer ``{"accepted", "reason", ...}`` to ``operator``'s signed
        confirm-clear (``confirm_clear`` False: a plain reset, which the monitor accepts only
        on its own evidence that the cell is clear); ``ConfirmClearRefused`` when nothing could
        be sent or nothing answered."""
        why = self.can(operator)
        if why is not None:
            raise ConfirmClearRefused(why, 403)
        with self._lock:  # one at a time: each names the latch its status read gave
            stop = threading.Event()
            skipped: list[str] = []  # status answers not the monitor's (its keys given)
            status = first_status(self.session, self.keys, self.timeout_s, stop,
                                  self.monitor_keys, skipped)
            if status is None:
                also = f" ({ignored_text(skipped)})" if skipped else ""
                raise ConfirmClearRefused(f"no monitor answered on {self.keys.status} within "
                                          f"{self.timeout_s:g} s{also}", 504)
            boot, latch = latch_of_status(status)
            if latch is None:
                raise ConfirmClearRefused(f"nothing to {'confirm' if confirm_clear else 'reset'}: "
                                          f"the monitor is not latched "
                                          f"(state {status.get('state')})")
            payload = reset_payload(operator, "", note, cell=self.cell,
                                    confirm_clear=confirm_clear,
                                    boot=boot, latch=latch)
            signature = self.signers[operator].sign(self.keys.reset, payload)
            answer = request_reset(self.session, self.keys.reset, payload, signature,
                                   self.timeout_s, self.monitor_keys)
        if answer is None:
            raise ConfirmClearRefused(f"no monitor answered on {self.keys.reset} within "
                                      f"{self.timeout_s:g} s", 504)
        return answer
