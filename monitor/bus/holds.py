"""Hand-over of holds on the bus: the Zenoh edge of ``monitor.tracking.handover``
(docs/consumer.md).

A monitor with ``[handover] peers`` publishes, at the bus's heartbeat rate, its holds of persons
lost inside zones and its recent departures on ``<prefix>safety/<role>/holds``, signed with its
command key (``monitor.wire.signing``; the payload names cell, role, boot, seq and wall), and takes
its peers' verified entries into ``Pipeline.handover`` (the loop's thread, as a driver sink).

It listens on every role's holds key: a message on the key of a role it does not expect,
unsigned, wrongly signed, malformed, for another cell, outside the clock window or replayed
(``seq`` not growing within one boot) is refused and counted (``holds_refused`` in the status,
one ``foreign_holds`` alert per burst), like forged commands (``monitor.bus.foreign``). A message
can only add holds, never end one; a peer that falls silent ends nothing either.

A flood cannot keep the genuine peer from being verified (issue 31: 64 zero bytes as
"signatures" spent the one shared budget of 100 checks/s, the peer went unverified, a latched
``handover_silent``). Each signed message *vouches* for the next ``AHEAD`` ones of its sender:
it carries the SHA-256 digests of random tokens (``next``) and the message with seq n reveals
its own token in the attachment (``signature || seq || token``, ``HoldsSender``). Checking a
token is one hash, no signature: a message whose token matches a digest its sender signed
before takes the sender's own *vouched* budget; every other one (the first of a boot, one after
more than ``AHEAD`` losses, and every forgery: nobody else knows a token before the peer sends
it) takes the sender's small *cold* budget, which a flood spends without touching the vouched
one. Budgets are per sender (the role whose key the message came on), so a flood on one peer's
key costs no other peer anything. A token copied off the wire after the peer revealed it vouches
for a message at most ``TRIES`` times and only until that seq was verified.
"""

from __future__ import annotations

import collections
import contextlib
import hashlib
import hmac
import json
import logging
import os
import threading
import time
from collections.abc import Callable, Mapping

import zenoh
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from monitor.tracking.handover import (
    HANDOVER_SCHEMA,
    MAX_ENTRIES,
    Entry,
    HandedHolds,
    HandoverConfig,
    overflow_entry,
    silent_peers,
)
from monitor.tracking.handover import entries_of as _entries_of
from monitor.types import Alert, Fault
from monitor.wire import payload as payload_json
from monitor.wire.busconfig import BusKeys
from monitor.wire.signing import SIGNATURE_BYTES, Signer, verify
from monitor.wire.verify_budget import VerifyBudget

_log = logging.getLogger("monitor.tracking.handover")
KINDS = ("unknown_role", "unsigned", "signature", "unchecked", "invalid", "stale", "replayed")
MAX_BOOTS = 64  # remembered (role, boot) seq counters: a flood cannot grow memory
AHEAD = 8  # messages each one vouches for: up to AHEAD - 1 lost in a row stay vouched
TOKEN_BYTES = 16
SEQ_BYTES = 8
ATTACHMENT_BYTES = SIGNATURE_BYTES + SEQ_BYTES + TOKEN_BYTES
TRIES = 4  # signature checks one vouched seq may cost (a token copied off the wire)
MAX_PAYLOAD = 64 * 1024  # a holds message of MAX_ENTRIES entries is a few kB


def token_digest(token: bytes) -> bytes:
    return hashlib.sha256(token).digest()[:TOKEN_BYTES]


class HoldsSender:
    """Builds this monitor's signed holds messages: seq growing from 1, each vouching for the
    next ``AHEAD`` (the digests of their tokens, signed) and revealing its own token."""

    def __init__(self, signer: Signer, key_expr: str, cell: str, role: str, boot: str) -> None:
        self.signer, self.key_expr = signer, key_expr
        self.cell, self.role, self.boot = cell, role, boot
        self.seq = 0
        self._tokens: dict[int, bytes] = {}

    def message(self, wall: float, entries: tuple[Entry, ...]) -> tuple[bytes, bytes]:
        """(payload, attachment) of the next message."""
        self.seq += 1
        n = self.seq
        for k in range(n, n + AHEAD + 1):
            self._tokens.setdefault(k, os.urandom(TOKEN_BYTES))
        token = self._tokens.pop(n)
        vouch = [token_digest(self._tokens[k]).hex() for k in range(n + 1, n + AHEAD + 1)]
        payload = holds_payload(self.cell, self.role, self.boot, n, wall, entries, vouch)
        return payload, (self.signer.sign(self.key_expr, payload) + n.to_bytes(SEQ_BYTES, "big")
                         + token)


class HoldsGate:
    """Verifies peers' holds messages (thread-safe: Zenoh callbacks run anywhere)."""

    def __init__(self, cell: str, prefix: str, own_role: str,
                 peers: Mapping[str, Ed25519PublicKey], *, wall_window_s: float = 5.0,
                 verify_per_s: float = 100.0, cold_per_s: float = 25.0) -> None:
        self.cell, self.own_role = cell, own_role
        self.keys = {role: BusKeys.of(prefix, role).holds for role in peers}
        self.peers = dict(peers)
        self.wall_window_s = wall_window_s
        self.verify_per_s = verify_per_s
        self._lock = threading.Lock()
        self._counts: collections.Counter[str] = collections.Counter()
        self._alerted: collections.Counter[str] = collections.Counter()
        self.verified: collections.Counter[str] = collections.Counter()  # role -> messages
        self._seq: dict[tuple[str, str], int] = {}
        # per sender: checks of vouched messages, and of all others (floods land there)
        self._vouched_budget = {role: VerifyBudget(verify_per_s) for role in peers}
        self._cold_budget = {role: VerifyBudget(cold_per_s) for role in peers}
        # role -> {seq: [token digest, tries]} vouched for by its last verified message
        self._vouch: dict[str, dict[int, list]] = {role: {} for role in peers}
        self.last_invalid = ""  # why the newest invalid message was refused

    def check(self, key_expr: str, payload: bytes, signature: bytes | None, now: float,
              wall_now: float) -> tuple[str, str, tuple[Entry, ...], float] | None:
        """(role, boot, entries, the sender's wall time) of a verified message, or None."""
        kind, out = self._sort(key_expr, payload, signature, now, wall_now)
        if kind:
            with self._lock:
                self._counts[kind] += 1
                if kind == "invalid":  # the reason of the newest invalid one, for its alert
                    self.last_invalid = str(out or "")
            return None
        return out

    def _sort(self, key_expr: str, payload: bytes, signature: bytes | None, now: float,
              wall_now: float):
        role = next((r for r, k in self.keys.items() if k == key_expr), None)
        if role is None:
            return "unknown_role", None
        if signature is None:
            return "unsigned", None
        if len(signature) not in (SIGNATURE_BYTES, ATTACHMENT_BYTES):
            return "signature", None
        if len(payload) > MAX_PAYLOAD:
            return "invalid", f"payload has {len(payload)} bytes (at most {MAX_PAYLOAD})"
        claimed, vouched = None, False
        if len(signature) == ATTACHMENT_BYTES:  # signature || seq || token (HoldsSender)
            tail, signature = signature[SIGNATURE_BYTES:], signature[:SIGNATURE_BYTES]
            claimed = int.from_bytes(tail[:SEQ_BYTES], "big")
            vouched = self._vouched(role, claimed, tail[SEQ_BYTES:])
        budget = (self._vouched_budget if vouched else self._cold_budget)[role]
        if not budget.take(now):
            return "unchecked", None
        if not verify(self.peers[role], key_expr, payload, signature):
            return "signature", None
        try:
            # bounded: deep nesting, 1e400, 10**400, NaN are refused here, before any field
            body = payload_json.load_object(payload, MAX_PAYLOAD)
            if body.get("schema") != HANDOVER_SCHEMA or body.get("cell") != self.cell \
                    or body.get("role") != role:
                return "invalid", "not a holds message of this cell and role"
            boot, seq, wall = body["boot"], body["seq"], body["wall"]
            if not isinstance(boot, str) or not isinstance(seq, int) or isinstance(seq, bool) \
                    or (claimed is not None and seq != claimed):
                return "invalid", "boot, seq or the attachment's seq malformed"
            listed, more = body["entries"], body.get("overflow", 0)
            if not isinstance(listed, list) or not isinstance(more, int) or isinstance(
                    more, bool) or more < 0:
                return "invalid", "entries or overflow malformed"
            entries = tuple(Entry.from_dict(e) for e in listed[:MAX_ENTRIES])
            more += max(0, len(listed) - MAX_ENTRIES)
        except (ValueError, KeyError, TypeError, AttributeError, OverflowError) as exc:
            return "invalid", str(exc).splitlines()[0][:160] if str(exc) else \
                type(exc).__name__
        # "not <=": a NaN wall (json reads NaN) is outside every window
        if not isinstance(wall, int | float) or isinstance(wall, bool) \
                or not abs(float(wall) - wall_now) <= self.wall_window_s:
            return "stale", None
        with self._lock:
            last = self._seq.get((role, boot))
            if last is not None and seq <= last:
                return "replayed", None
            if last is None and len(self._seq) >= MAX_BOOTS:
                self._seq.pop(next(iter(self._seq)))
            self._seq[(role, boot)] = seq
            self._vouch[role] = _vouch_of(body.get("next"), seq)
            self.verified[role] += 1
        if more:  # the persons left off could be anywhere: never silently lost
            entries += (overflow_entry(len(entries) + more, float(wall)),)
        return "", (role, boot, entries, float(wall))

    def _vouched(self, role: str, seq: int, token: bytes) -> bool:
        """The token of ``seq`` is the one its sender's last verified message vouched for (one
        hash; at most ``TRIES`` times per seq)."""
        with self._lock:
            entry = self._vouch[role].get(seq)
            if entry is None or entry[1] >= TRIES:
                return False
            if not hmac.compare_digest(entry[0], token_digest(token)):
                return False
            entry[1] += 1
            return True

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def alert(self, now: float) -> Alert | None:
        """One alert for the messages refused since the last call, or None."""
        with self._lock:
            new = self._counts - self._alerted
            self._alerted = collections.Counter(self._counts)
        if not new:
            return None
        what = ", ".join(f"{k} {new[k]}" for k in KINDS if new.get(k))
        return Alert("foreign_holds", "warning",
                     f"{sum(new.values())} holds messages refused ({what}): they add and end "
                     "nothing; someone else publishes on the cell's holds keys", "handover",
                     now, details={"new": dict(new)})


def _vouch_of(digests, seq: int) -> dict[int, list]:
    """seq -> [digest, tries] of the messages after ``seq`` a verified one vouched for."""
    if not isinstance(digests, list):
        return {}
    out = {}
    for k, d in enumerate(digests[:AHEAD]):
        if isinstance(d, str) and len(d) == 2 * TOKEN_BYTES:
            with contextlib.suppress(ValueError):
                out[seq + 1 + k] = [bytes.fromhex(d), 0]
    return out


def holds_payload(cell: str, role: str, boot: str, seq: int, wall: float,
                  entries: tuple[Entry, ...], vouch: list[str] | None = None) -> bytes:
    """The signed message body: at most ``MAX_ENTRIES`` entries (holds first), and in
    ``overflow`` how many more there were (a receiver then holds every protective zone);
    ``next``: the token digests of the next messages (``HoldsSender``)."""
    return json.dumps({"schema": HANDOVER_SCHEMA, "cell": cell, "role": role, "boot": boot,
                       "seq": seq, "wall": wall, "mono": time.monotonic(),
                       "entries": [e.to_dict() for e in entries[:MAX_ENTRIES]],
                       "overflow": max(0, len(entries) - MAX_ENTRIES),
                       **({"next": vouch} if vouch else {})}).encode()


class HoldsLink:
    """The driver sink that publishes this monitor's holds and takes its peers' (use it while
    the bus is open; ``close`` undeclares). ``pipeline.handover`` is set here."""

    def __init__(self, bus, pipeline, config: HandoverConfig,
                 peers: Mapping[str, Ed25519PublicKey], signer: Signer,
                 wall: Callable[[], float] = time.time) -> None:
        self.bus, self.pipeline, self.config = bus, pipeline, config
        self.signer, self.wall = signer, wall
        cfg = bus.config
        self.key = BusKeys.of(cfg.key_prefix, cfg.role).holds
        self.gate = HoldsGate(cfg.cell, cfg.key_prefix, cfg.role, peers)
        tracker = next((c.tracker for c in pipeline.cameras.values() if c.tracker), None)
        walk = tracker.config.walk_speed_mps if tracker is not None else 1.5
        pipeline.handover = HandedHolds(walk, config.reach_s, when=pipeline.when)
        self._inbox: collections.deque = collections.deque(maxlen=256)
        self._sender: HoldsSender | None = None  # made at the first publish (the bus's boot)
        self._last_put: float | None = None
        self._started = time.monotonic()
        self._heard: dict[str, float | None] = dict.fromkeys(peers)
        self._boots: dict[str, str] = {}  # role -> the boot of its newest accepted message
        self._restarted: dict[str, tuple[str, float]] = {}  # role -> (why, my clock then)
        self._period = 1.0 / cfg.heartbeat_hz
        s = bus.session
        self._pub = s.declare_publisher(self.key, encoding="application/json",
                                        priority=zenoh.Priority.REAL_TIME, express=True)
        self._sub = s.declare_subscriber(cfg.key_prefix + "safety/*/holds", self._on_sample,
                                         allowed_origin=zenoh.Locality.REMOTE)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            key = str(sample.key_expr)
            if key == self.key:
                return  # our own key (another instance of our role is a duplicate_monitor)
            signature = sample.attachment.to_bytes() if sample.attachment is not None else None
            received, wall_now = time.monotonic(), self.wall()
            taken = self.gate.check(key, sample.payload.to_bytes(), signature, received,
                                    wall_now)
        except Exception:  # nothing a sender does may kill this callback
            return
        if taken is not None:
            role, boot, entries, wall = taken
            # heard as of when the peer *sent* it: a stream held back on the path (each message
            # signed and in sequence, but seconds late) is as silent as its age says
            sent = received - max(0.0, wall_now - wall)
            last = self._heard.get(role)
            self._heard[role] = sent if last is None else max(last, sent)
            known = self._boots.setdefault(role, boot)
            if known != boot:  # the peer restarted: what its old run had lost is gone
                self._boots[role] = boot
                self._restarted[role] = (f"{role} restarted (boot {known[:8]} -> "
                                         f"{boot[:8]})", received)
            self._inbox.append((role, boot, entries))

    def faults(self) -> tuple[Fault, ...]:
        """``handover_silent`` STOPs of peers not heard for ``peer_timeout_s`` (the live
        feed polls it every step, like the bus's ``duplicate_monitor``)."""
        counts = self.gate.counts()
        refused = ", ".join(f"{k} {counts[k]}" for k in KINDS if counts.get(k))
        now = time.monotonic()
        restarted = tuple(
            Fault("handover_restarted", f"{why}: persons its old run had lost, or that left "
                  "its view while it was down, are in no list; an operator must look", True,
                  "handover", latch=True)
            for why, at in self._restarted.values() if now - at <= self.config.peer_timeout_s)
        return restarted + silent_peers(dict(self._heard), self._started, now,
                                        self.config.peer_timeout_s, self.config.keep_s,
                                        refused)

    def on_step(self, step) -> None:
        now = step.result.now
        handed = self.pipeline.handover
        while self._inbox:
            role, boot, entries = self._inbox.popleft()
            for hold in handed.take(role, boot, entries, self.pipeline.cell, now, self.wall()):
                _log.warning("hand-over: %s: %s", role, hold.describe())
        if self._last_put is not None and now - self._last_put < self._period:
            return
        self._last_put = now
        self.publish(now)
        alert = self.gate.alert(now)
        if alert is not None:
            self.bus.publish_alert(alert)
        self.bus.update_status(holds_refused=self.gate.counts(),
                               holds_taken=[h.describe() for h in handed.holds])

    def publish(self, now: float) -> None:
        """This monitor's holds and departures now, signed."""
        tracks = {cid: cam.tracker.tracks for cid, cam in self.pipeline.cameras.items()
                  if cam.tracker is not None}
        entries = _entries_of(tracks, time.monotonic(), self.wall(), self.config.keep_s)
        if self._sender is None:
            self._sender = HoldsSender(self.signer, self.key, self.bus.config.cell,
                                       self.bus.config.role, self.bus.boot)
        payload, attachment = self._sender.message(self.wall(), entries)
        with contextlib.suppress(Exception):  # a failed put: the peer sees silence, no RUN
            self._pub.put(payload, attachment=attachment)

    def close(self) -> None:
        for entity in (self._sub, self._pub):
            with contextlib.suppress(Exception):
                entity.undeclare()


def start_handover(config, pipeline, bus) -> HoldsLink | None:
    """The hand-over sink of ``monitor run`` (None without ``[handover] peers``)."""
    from monitor.wire.signing import load_private_key, load_public_key

    peers = config.handover.peers
    if not peers:
        return None
    keys = {role: load_public_key(path) for role, path in peers.items()}
    link = HoldsLink(bus, pipeline, config.handover, keys,
                     load_private_key(config.bus.signing_key))
    _log.info("hand-over: publishing holds on %s, taking those of %s", link.key,
              ", ".join(sorted(peers)))
    models = pipeline.cell.camera_models if pipeline.cell is not None else {}
    for cam in (c.id for c in config.cameras if c.id not in models):
        _log.warning("hand-over: camera %s has no calibration: its persons have no floor point "
                     "and are never handed over (docs/consumer.md)", cam)
    return link
