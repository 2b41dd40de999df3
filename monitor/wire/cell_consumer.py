"""The consumer rule for a cell watched by several monitors, each with its role and its key.

Each monitor of the cell has a role (``[bus] role``, e.g. ``monitor-a``), its own signing key,
and publishes its own commands on ``<prefix>safety/<role>/command`` (role "": the cell's only
monitor, ``<prefix>safety/command``). The consumer is told which roles to expect, with each
role's public key, and ``CellWatchdog`` holds one ``CommandWatchdog`` per expected role (that
role's key, that role's command key, that role's liveliness tokens). The cell's verdict is the
most restrictive of all expected roles:

- STOP unless every expected role's own verdict is RUN or SLOW: a missing role (no command yet),
  a stale one (ttl, liveliness token vanished: killed, frozen, cut off), a role whose sequence
  broke, or two live instances of one role (duplicate), each said with the role's name
  (``monitor-b: silence: ...``);
- STOP while an *unknown* monitor is on the cell: a well-formed command for this cell, within
  the clock window, on the command key of a role not expected, or a liveliness token under a
  role not expected (``unknown_monitor: monitor-c ...``), for ``UNKNOWN_HOLD_S`` after the last
  sign of it. The consumer has no key for it, so it cannot tell a monitor from a forger here:
  a forged packet can force STOP (a nuisance), never RUN;
- otherwise SLOW if any role says SLOW, at the lowest speed of all roles, else RUN.

``on_command`` takes the key the command arrived on (``subscribe_cell`` hands it over): the
role is the key's, and the signature covers the key, so a role's key cannot speak for another.
"""

from __future__ import annotations

import collections
import contextlib
import time
from collections.abc import Callable, Mapping

import zenoh

from monitor.wire.busconfig import BusKeys
from monitor.wire.consumer import (
    DEFAULT_CLOCK_SYNC_MS,
    DEFAULT_MAX_TTL_MS,
    MAX_TRACKED,
    CommandWatchdog,
    Verdict,
    parse_command,
)

UNKNOWN_HOLD_S = 2.0  # an unknown monitor's last command or token keeps STOP this long


def role_name(role: str) -> str:
    return role or "(no role)"


class CellWatchdog:
    """The consumer rule over every expected monitor of one cell (see the module doc).

    ``expected``: role -> that role's trusted public keys (empty: unauthenticated, a bench
    only). ``prefix``: the cell's key prefix (``workcell/<cell>/``). The other arguments are
    ``CommandWatchdog``'s, applied to every role."""

    def __init__(self, expected: Mapping[str, tuple], prefix: str, *,
                 max_ttl_ms: float | None = DEFAULT_MAX_TTL_MS, require_liveliness: bool = True,
                 cell: str | None = None,
                 clock_sync_ms: float = DEFAULT_CLOCK_SYNC_MS) -> None:
        if not expected:
            raise ValueError("expect at least one monitor role")
        self.prefix = prefix if prefix.endswith("/") else prefix + "/"
        self.cell = cell
        self.clock_sync_ms = clock_sync_ms
        self.keys = {role: BusKeys.of(self.prefix, role) for role in expected}
        self.dogs = {role: CommandWatchdog(
            max_ttl_ms, None, require_liveliness, public_keys=tuple(keys), cell=cell,
            key_expr=self.keys[role].command, clock_sync_ms=clock_sync_ms)
            for role, keys in expected.items()}
        self.max_ttl_ms = next(iter(self.dogs.values())).max_ttl_ms
        # unknown role -> (last sign of it, what it was); tokens of unknown roles
        self.unknown: dict[str, tuple[float, str]] = {}
        self.unknown_alive: dict[str, set[str]] = collections.defaultdict(set)
        self.own_rejected: collections.Counter = collections.Counter()
        self.last_rejection = ""

    # --- what CommandWatchdog's users read -----------------------------------------------------

    @property
    def public_keys(self) -> tuple:
        return tuple(k for dog in self.dogs.values() for k in dog.public_keys)

    @property
    def rejected(self) -> collections.Counter:
        total = collections.Counter(self.own_rejected)
        for dog in self.dogs.values():
            total.update(dog.rejected)
        return total

    def role_of_key(self, key_expr: str | None, last: str) -> str | None:
        """The role whose ``last`` key (command, or a liveliness prefix) ``key_expr`` is;
        None for any other key."""
        if key_expr is None:
            return ""
        base = self.prefix + "safety/"
        key = str(key_expr)
        if not key.startswith(base):
            return None
        parts = key[len(base):].split("/")
        if last == "command":
            if parts == ["command"]:
                return ""
            return parts[0] if len(parts) == 2 and parts[1] == "command" else None
        return None

    # --- input ---------------------------------------------------------------------------------

    def on_command(self, payload: bytes, now: float, signature: bytes | None = None,
                   wall_now: float | None = None, key_expr: str | None = None) -> str | None:
        """Feed one command and the key it arrived on; why it was dropped, or None. An unknown
        role's command returns ``unknown_monitor`` (and holds the cell at STOP)."""
        role = self.role_of_key(key_expr, "command")
        if role is None:
            return self._reject("other_key", str(key_expr))
        dog = self.dogs.get(role)
        if dog is not None:
            why = dog.on_command(payload, now, signature, wall_now)
            if why is not None:
                self.last_rejection = f"{role_name(role)}: {dog.last_rejection}"
            return why
        return self._unknown_command(role, payload, now, wall_now)

    def _reject(self, code: str, detail: str) -> str:
        self.own_rejected[code] += 1
        self.last_rejection = f"{code}: {detail}"
        return code

    def _unknown_command(self, role: str, payload: bytes, now: float,
                         wall_now: float | None) -> str:
        try:
            body = parse_command(payload)
        except Exception:
            return self._reject("invalid", f"on the key of unknown role {role_name(role)}")
        if self.cell is not None and body.get("cell", self.cell) != self.cell:
            return self._reject("other_cell", str(body.get("cell")))
        wall = body.get("wall")
        if wall_now is not None:
            ttl = min(float(body["ttl_ms"]), self.max_ttl_ms)
            late_ms = None if wall is None else (wall_now - float(wall)) * 1000.0
            if late_ms is None or not -self.clock_sync_ms <= late_ms <= self.clock_sync_ms + ttl:
                return self._reject("window", f"a command of unknown role {role_name(role)} "
                                    "outside the clock window (a recording)")
        self._note_unknown(role, now, f"commands from instance {body['instance']}")
        self.own_rejected["unknown_monitor"] += 1
        self.last_rejection = f"unknown_monitor: {role_name(role)}"
        return "unknown_monitor"

    def _note_unknown(self, role: str, now: float, what: str) -> None:
        if role not in self.unknown and len(self.unknown) >= MAX_TRACKED:
            oldest = min(self.unknown, key=lambda r: self.unknown[r][0])
            del self.unknown[oldest]
        self.unknown[role] = (now, what)

    def on_liveliness(self, key: str, alive: bool, now: float | None = None) -> None:
        """A liveliness token of any monitor of the cell appeared or vanished."""
        base = self.prefix + "safety/alive/"
        key = str(key)
        if not key.startswith(base):
            return
        parts = key[len(base):].split("/")
        if len(parts) == 1:
            role, instance = "", parts[0]
        elif len(parts) == 2:
            role, instance = parts
        else:
            return
        dog = self.dogs.get(role)
        if dog is not None:
            dog.on_liveliness(key, alive)
            return
        tokens = self.unknown_alive[role]
        if alive:
            if len(tokens) < MAX_TRACKED and len(self.unknown_alive) <= MAX_TRACKED:
                tokens.add(instance)
        else:
            tokens.discard(instance)
            if now is not None:  # a token just gone still counts for a while
                self._note_unknown(role, now, f"liveliness token of {instance} (vanished)")

    # --- verdict -------------------------------------------------------------------------------

    def unknown_monitors(self, now: float) -> list[str]:
        out = []
        for role, tokens in sorted(self.unknown_alive.items()):
            if tokens:
                out.append(f"{role_name(role)} (live: {', '.join(sorted(tokens)[:2])})")
        for role, (seen, what) in sorted(self.unknown.items()):
            if 0 <= now - seen <= UNKNOWN_HOLD_S and not self.unknown_alive.get(role):
                out.append(f"{role_name(role)} ({what})")
        return out

    def verdicts(self, now: float) -> dict[str, Verdict]:
        return {role: dog.verdict(now) for role, dog in sorted(self.dogs.items())}

    def verdict(self, now: float) -> Verdict:
        each = self.verdicts(now)
        unknown = self.unknown_monitors(now)
        stops = [(role, v) for role, v in each.items() if v.state == "STOP"]
        if unknown:
            text = "; ".join(unknown)
            reasons = [f"unknown_monitor: {text} on cell {self.cell or self.prefix}: not an "
                       "expected monitor (a third monitor, or its key is not expected)"]
            reasons += [f"{role_name(r)}: {_why(v)}" for r, v in stops]
            first = stops[0][1] if stops else None
            return Verdict("STOP", 0.0, "; ".join(reasons), first.seq if first else None,
                           first.command if first else None, "unknown_monitor")
        if stops:
            # a consumer-rule STOP (silence, duplicate, ...) names itself before a monitor's
            # own STOP command; the command shown is the first stopping role's
            stops.sort(key=lambda rv: rv[1].code == "")
            role, first = stops[0]
            reason = "; ".join(f"{role_name(r)}: {_why(v)}" for r, v in stops)
            return Verdict("STOP", 0.0, reason, first.seq, first.command, first.code)
        role, slowest = min(each.items(), key=lambda rv: (rv[1].speed_scale, rv[0]))
        state = "SLOW" if any(v.state == "SLOW" for v in each.values()) else "RUN"
        if state == "SLOW" and slowest.state != "SLOW":  # equal speeds: name the SLOW one
            role, slowest = next((r, v) for r, v in each.items() if v.state == "SLOW")
        reason = f"{role_name(role)}: {_why(slowest)}" if state == "SLOW" else ""
        return Verdict(state, slowest.speed_scale, reason, slowest.seq, slowest.command, "")


def _why(v: Verdict) -> str:
    if v.reason:
        return v.reason
    reasons = (v.command or {}).get("reasons")
    if isinstance(reasons, list):
        text = "; ".join(str(r.get("message", r.get("code", ""))) for r in reasons
                         if isinstance(r, dict))
        if text:
            return f"{v.state} {text}"
    return v.state


def subscribe_cell(session: zenoh.Session, prefix: str, inbox,
                   clock: Callable[[], float] = time.monotonic) -> list:
    """Commands of every role (with their signature, both arrival clocks and their key),
    alerts and liveliness tokens of every monitor of the cell into ``inbox``."""
    p = prefix if prefix.endswith("/") else prefix + "/"

    def attachment(s) -> bytes | None:
        return s.attachment.to_bytes() if s.attachment is not None else None

    def put(kind: str, *item) -> None:
        inbox.put(kind, (kind, *item))

    def on_command(s) -> None:
        put("command", s.payload.to_bytes(), attachment(s), clock(), time.time(),
            str(s.key_expr))

    def on_alert(s) -> None:
        put("alert", s.payload.to_bytes(), attachment(s), clock())

    entities = []
    try:
        for key in (p + "safety/command", p + "safety/*/command"):
            entities.append(session.declare_subscriber(key, on_command))
        for key in (p + "safety/alert", p + "safety/*/alert"):
            entities.append(session.declare_subscriber(key, on_alert))
        entities.append(session.liveliness().declare_subscriber(
            p + "safety/alive/**", lambda s: put(
                "alive", str(s.key_expr), s.kind == zenoh.SampleKind.PUT, clock()),
            history=True))
    except BaseException:
        for e in entities:
            with contextlib.suppress(Exception):
                e.undeclare()
        raise
    return entities


def parse_expect(items: list[str], load_key: Callable[[str], object]) -> dict[str, tuple]:
    """``ROLE=KEYFILE`` options into role -> (public key, ...); a role may be given twice
    (two keys during a key change). ValueError names the bad item."""
    from monitor.wire.busconfig import checked_role

    out: dict[str, tuple] = {}
    for item in items:
        role, sep, path = item.partition("=")
        if not sep or not path:
            raise ValueError(f"--expect {item!r}: give ROLE=KEYFILE (e.g. "
                             "monitor-a=monitor-a.key.pub)")
        try:
            checked_role(role)
        except ValueError as exc:
            raise ValueError(f"--expect {item!r}: {exc}") from None
        out[role] = (*out.get(role, ()), load_key(path))
    return out
