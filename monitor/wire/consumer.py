"""The consumer-side rule for ``safety/command`` (what a robot controller runs), as a pure class.

The bus is a "black channel" (IEC 61784-3): it may lose, repeat, reorder, delay, corrupt or
forge messages. The consumer therefore trusts a command only when all of these hold, checked in
this order (docs/consumer.md gives the same list for ports to other languages):

1. the payload is a JSON object no larger than ``MAX_PAYLOAD`` with every field of the right
   type and range (finite numbers, ``seq`` a positive integer below 2**53, known state, speed
   within 0..1 and 0 for STOP); anything else is dropped, never raised;
2. it is signed by a trusted monitor key (Ed25519 over the exact payload bytes, see
   ``monitor.wire.signing``) -- when the consumer has keys, unsigned or wrongly signed is dropped;
3. it names the expected cell (and instance, when one is followed);
4. its ``wall`` time is at most ``clock_sync_ms`` ahead of the consumer's clock and at most
   ``clock_sync_ms`` + ttl behind it (recordings, and genuine commands relayed late: a
   command older than the declared clock-sync accuracy plus its ttl says nothing about now);
5. its ``boot`` is not one the consumer has already seen replaced -- by a newer boot (signed
   ``boot_wall``, the monitor's start time) of any instance, or by another boot of the same
   instance -- whatever the clock window, and its ``seq`` grew within that boot (repeats and
   reordering; a seq going backwards forces STOP until a newer one);

and then the cell is STOP unless the newest accepted command is younger than
``min(command ttl_ms, max_ttl_ms)`` -- the consumer's own cap always applies -- the sender's
liveliness token is present, and no second monitor is live on the cell.

``now`` is the consumer's monotonic clock in seconds; ``wall_now`` its Unix time.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

from monitor.wire import payload as payload_json
from monitor.wire.signing import verify

COMMAND_SCHEMA = "workcell.safety.command/1"
STATES = ("RUN", "SLOW", "STOP")
MAX_PAYLOAD = 64 * 1024
MAX_SEQ = 2**53  # exact in every JSON implementation
MAX_TTL_MS = 60_000.0
DEFAULT_MAX_TTL_MS = 1000.0
MAX_ID = 128
MAX_TRACKED = 256  # boots / instances remembered (a flood of forged ids cannot grow memory)
# how closely the monitor's and the consumer's wall clocks agree, as the deployment declares it:
# one host, or a LAN synchronised by NTP/PTP well within this (docs/consumer.md)
DEFAULT_CLOCK_SYNC_MS = 100.0


@dataclass(frozen=True)
class Verdict:
    """What a controller following the consumer rule should do now."""

    state: str
    speed_scale: float
    reason: str  # "" when the monitor's command is followed as is
    seq: int | None = None
    command: dict | None = None
    # "", "no_command", "ttl", "sequence", "liveliness", "duplicate_monitor": stable, for machines
    code: str = ""


class InvalidCommand(ValueError):
    """A command payload that fails validation (the message says which field)."""


def _number(body: dict, key: str, lo: float, hi: float) -> float:
    value = body.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InvalidCommand(f"{key} is not a number")
    try:
        value = float(value)
    except OverflowError:  # a JSON integer beyond the float range
        raise InvalidCommand(f"{key} not within {lo}..{hi}") from None
    if not (math.isfinite(value) and lo <= value <= hi):
        raise InvalidCommand(f"{key} not within {lo}..{hi}")
    return value


def _text(body: dict, key: str) -> str:
    value = body.get(key)
    if not isinstance(value, str) or not 0 < len(value) <= MAX_ID:
        raise InvalidCommand(f"{key} is not a short string")
    return value


def parse_command(payload: bytes) -> dict:
    """Validate a command payload; InvalidCommand names the first bad field."""
    if not isinstance(payload, bytes | bytearray) or len(payload) > MAX_PAYLOAD:
        raise InvalidCommand("payload too large")
    try:
        body = payload_json.load_object(payload, MAX_PAYLOAD)
    except payload_json.PayloadError as exc:
        raise InvalidCommand(str(exc)) from None
    if body.get("schema") != COMMAND_SCHEMA:
        raise InvalidCommand("schema")
    seq = body.get("seq")
    if isinstance(seq, bool) or not isinstance(seq, int) or not 0 < seq < MAX_SEQ:
        raise InvalidCommand("seq is not an integer within 1..2**53")
    _text(body, "boot")
    _text(body, "instance")
    if body.get("state") not in STATES:
        raise InvalidCommand("state")
    scale = _number(body, "speed_scale", 0.0, 1.0)
    if body["state"] == "STOP" and scale != 0.0:
        raise InvalidCommand("STOP with a speed above 0")
    _number(body, "ttl_ms", 1e-3, MAX_TTL_MS)
    if "cell" in body:
        _text(body, "cell")
    if "wall" in body:
        _number(body, "wall", 0.0, 1e11)
    if "boot_wall" in body:
        _number(body, "boot_wall", 0.0, 1e11)
    if "latched" in body and not isinstance(body["latched"], bool):
        raise InvalidCommand("latched is not a boolean")
    if "reasons" in body and not isinstance(body["reasons"], list):
        raise InvalidCommand("reasons is not a list")
    return body


class CommandWatchdog:
    """The consumer rule (see the module doc). Robot-controller integrators port this class.

    ``public_keys``: trusted monitor keys (Ed25519 public keys); when given, only commands
    signed by one of them count. ``max_ttl_ms`` caps every command's ttl (default 1000 ms).
    ``cell``/``instance``: accept only this cell / this monitor instance.
    ``clock_sync_ms``: the declared accuracy of the clock sync between monitor and consumer;
    a command's ``wall`` may be this far ahead of ``wall_now`` and this plus its ttl behind it
    (checked when the caller passes ``wall_now``, the receive time). ``key_expr``: the key the
    commands arrive on (part of the signature).
    """

    def __init__(self, max_ttl_ms: float | None = DEFAULT_MAX_TTL_MS,
                 instance: str | None = None, require_liveliness: bool = True, *,
                 public_keys: tuple = (), cell: str | None = None,
                 key_expr: str | None = None,
                 clock_sync_ms: float = DEFAULT_CLOCK_SYNC_MS) -> None:
        if max_ttl_ms is None:
            max_ttl_ms = DEFAULT_MAX_TTL_MS
        if not (math.isfinite(max_ttl_ms) and 0 < max_ttl_ms <= MAX_TTL_MS):
            raise ValueError(f"max_ttl_ms must be within (0, {MAX_TTL_MS:.0f}] ms")
        self.max_ttl_ms = float(max_ttl_ms)
        self.instance = instance
        self.require_liveliness = require_liveliness
        self.public_keys = tuple(public_keys)
        self.cell = cell
        self.key_expr = key_expr or f"workcell/{cell or 'cell1'}/safety/command"
        if not (math.isfinite(clock_sync_ms) and 0 <= clock_sync_ms <= MAX_TTL_MS):
            raise ValueError(f"clock_sync_ms must be within [0, {MAX_TTL_MS:.0f}] ms")
        self.clock_sync_ms = float(clock_sync_ms)
        self.last: dict | None = None
        self.received: float | None = None
        self.boot: str | None = None
        self.seq_error: str | None = None
        self.alive: set[str] = set()
        self.seen_alive: set[str] = set()
        self.retired_boots: collections.OrderedDict[str, None] = collections.OrderedDict()
        self.newest_boot: tuple[float, str] | None = None  # (boot_wall, boot) of the newest
        self.last_by_instance: dict[str, float] = {}  # instance -> receive time of valid command
        self.rejected: collections.Counter = collections.Counter()
        self.last_rejection: str = ""

    def _reject(self, code: str, detail: str = "") -> str:
        self.rejected[code] += 1
        self.last_rejection = f"{code}: {detail}" if detail else code
        return code

    def on_command(self, payload: bytes, now: float, signature: bytes | None = None,
                   wall_now: float | None = None) -> str | None:
        """Feed one received payload (and its attachment); returns why it was dropped
        (``invalid``, ``unsigned``, ``signature``, ``other_cell``, ``other_instance``,
        ``window``, ``old_boot``, ``seq``) or None when accepted. Never raises."""
        try:
            body = parse_command(payload)
        except InvalidCommand as exc:
            return self._reject("invalid", str(exc))
        except Exception as exc:  # belt and braces: the consumer itself must never crash
            return self._reject("invalid", type(exc).__name__)
        if self.public_keys:
            if signature is None:
                return self._reject("unsigned")
            if not any(verify(k, self.key_expr, bytes(payload), signature)
                       for k in self.public_keys):
                return self._reject("signature")
        if self.cell is not None and body.get("cell", self.cell) != self.cell:
            return self._reject("other_cell", str(body.get("cell")))
        instance, boot, seq = body["instance"], body["boot"], body["seq"]
        if self.instance is not None and instance != self.instance:
            # a validly signed command of another instance is a second monitor on this cell
            if self.public_keys:
                self._note_instance(instance, now)
            return self._reject("other_instance", instance)
        if wall_now is not None:
            wall = body.get("wall")
            late_ms = None if wall is None else (wall_now - float(wall)) * 1000.0
            ttl = min(float(body["ttl_ms"]), self.max_ttl_ms)
            if late_ms is None or not -self.clock_sync_ms <= late_ms <= self.clock_sync_ms + ttl:
                return self._reject("window", "no wall time" if late_ms is None else
                                    f"sent {late_ms:.0f} ms before it arrived (allowed "
                                    f"-{self.clock_sync_ms:.0f}..{self.clock_sync_ms + ttl:.0f})")
        order = (float(body["boot_wall"]), boot) if "boot_wall" in body else None
        if boot in self.retired_boots or (
                order is not None and self.newest_boot is not None and order < self.newest_boot):
            # a boot older than one already seen: a restarted monitor's past, or a recording
            # of it; never followed again (still a monitor heard, for the duplicate check)
            self._retire(boot)
            self._note_instance(instance, now)
            return self._reject("old_boot", boot)
        if self.last is not None and boot == self.boot and seq <= int(self.last["seq"]):
            self.seq_error = f"seq went backwards ({seq} after {self.last['seq']})"
            return self._reject("seq", self.seq_error)
        if self.last is not None and boot != self.boot and self.boot is not None \
                and str(self.last.get("instance")) == instance:
            self._retire(self.boot)  # the monitor restarted: its old boot never counts again
        if order is not None and (self.newest_boot is None or order > self.newest_boot):
            if self.newest_boot is not None:
                self._retire(self.newest_boot[1])  # a newer boot retires the older for good
            self.newest_boot = order
        self._note_instance(instance, now)
        self.last, self.received, self.boot, self.seq_error = body, now, boot, None
        return None

    def _retire(self, boot: str) -> None:
        self.retired_boots[boot] = None
        while len(self.retired_boots) > MAX_TRACKED:
            self.retired_boots.popitem(last=False)

    def _note_instance(self, instance: str, now: float) -> None:
        self.last_by_instance[instance] = now
        if len(self.last_by_instance) > MAX_TRACKED:
            oldest = min(self.last_by_instance, key=self.last_by_instance.get)
            del self.last_by_instance[oldest]

    def on_liveliness(self, key: str, alive: bool) -> None:
        instance = str(key).rsplit("/", 1)[-1]
        if alive:
            if len(self.alive) < MAX_TRACKED:
                self.alive.add(instance)
            if len(self.seen_alive) < MAX_TRACKED:
                self.seen_alive.add(instance)
        else:
            self.alive.discard(instance)

    def live_instances(self, now: float) -> list[str]:
        """Monitors heard from within the ttl cap, or holding a liveliness token."""
        recent = {i for i, t in self.last_by_instance.items()
                  if 0 <= (now - t) * 1000.0 <= self.max_ttl_ms}
        return sorted(recent | (self.alive if self.require_liveliness else set()))

    def verdict(self, now: float) -> Verdict:
        last = self.last
        if last is None:
            return Verdict("STOP", 0.0, "silence: no command received yet", code="no_command")
        seq = int(last["seq"])
        if self.seq_error:
            return Verdict("STOP", 0.0, f"sequence: {self.seq_error}", seq, last, "sequence")
        ttl = min(float(last["ttl_ms"]), self.max_ttl_ms)
        age_ms = (now - (self.received or 0.0)) * 1000.0
        if not 0 <= age_ms <= ttl:  # a clock going backwards is no excuse either
            return Verdict("STOP", 0.0, f"silence: last command {age_ms:.0f} ms ago "
                           f"(ttl {ttl:.0f} ms)", seq, last, "ttl")
        live = self.live_instances(now)
        if len(live) > 1:
            return Verdict("STOP", 0.0, f"duplicate_monitor: {len(live)} monitors live on "
                           f"this cell ({', '.join(live[:4])}); run one per cell", seq, last,
                           "duplicate_monitor")
        inst = str(last.get("instance", ""))
        if self.require_liveliness and inst not in self.alive:
            why = "vanished" if inst in self.seen_alive else "not seen"
            return Verdict("STOP", 0.0, f"silence: liveliness token of {inst} {why}", seq, last,
                           "liveliness")
        return Verdict(last["state"], float(last["speed_scale"]), "", seq, last)
