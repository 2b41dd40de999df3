"""A changed zone file applied to the running service, only when an operator signed it.

``ZoneApplies`` is the bus side: a queryable on ``<prefix>safety/zones/apply`` that checks each
request (``monitor.cases.zone_apply.ApplyGate``: listed operator, signature, cell, this boot, time,
request id), answers a refused one at once and queues the others for the safety loop. Every
answer (refused at the bus, refused or applied by the loop) is signed with the monitor's key and
names the request it answers and the monitor (``SafetyBus.signed_answer``), so ``monitor zones
apply --monitor-key`` believes no rogue responder's "zones applied".

``LiveZones`` is the loop side (called from ``LiveFeed.inputs``, between two steps, in the loop's
own thread: the pipeline is never touched from another thread). For each request it re-reads
the zone file from the service's configured path, refuses unless the file's zone-set hash is
the signed one ("the file changed after you signed") or the draft beside it has that hash (the
console's edits that weaken protection wait there, ``monitor.console.zones_api``: once every
check below holds the draft becomes the zone file, so a restart loads what was signed),
validates it as at start
(``monitor.service.setup.zone_checks``; the cameras and their sizes must stay, they need a restart),
builds what derives from it (prepared zones, watch regions of the health checks) and only then
swaps it into the pipeline (``Pipeline.swap_cell``), the bus (``config_hash`` of the status and
of every command) and the recorder, with a ``zones_applied`` alert naming the operator and the
old and new hashes. A refused apply changes nothing and gets a one-line reason (answered,
alerted as ``zones_apply_refused``, logged).

Why apply at once with a forced STOP rather than wait for a STOP: waiting would leave a signed
change pending for an unknown time and apply it at a moment nobody chose (or tempt operators to
provoke a STOP). Applied at once, the cell STOPs (``zones_applying``) until every camera has a
frame checked on the new zones, then the policy's clear_time runs on the new zones before RUN,
as after a start: no RUN is ever decided on a mix of the two zone sets.
"""

from __future__ import annotations

import collections
import contextlib
import threading
import time
from collections.abc import Callable

import numpy as np

from monitor.cases.zone_apply import APPLY_ANSWER_SCHEMA, ApplyGate, ApplyRefused, ApplyRequest
from monitor.errors import ConfigError, InputError
from monitor.types import Alert
from monitor.wire.answers import request_digest
from monitor.wire.request_desk import query_request
from monitor.wire.resets import MAX_RESET_PAYLOAD
from monitor.wire.signed_requests import operator_of
from monitor.wire.signing import load_operators
from monitor.zones.files import draft_path, promote_draft

APPLIED = "zones_applied"
REFUSED = "zones_apply_refused"
MAX_PENDING = 8


class ZoneApplies:
    """The bus side (Zenoh callback threads): verified requests queued for the loop."""

    def __init__(self, bus) -> None:
        self.bus = bus
        self.key = bus.keys.zones_apply
        cfg = bus.config
        operators = load_operators(cfg.operators_file) if cfg.operators_file else None
        self._gate = ApplyGate(operators, cfg.cell, self.key, cfg.reset_window_s)
        self._lock = threading.Lock()
        # (the request, its query, the request's SHA-256 its answers name)
        self._queue: collections.deque[tuple[ApplyRequest, object, str]] = collections.deque()
        self._refused: collections.deque[Alert] = collections.deque(maxlen=16)
        self.refused = 0
        self._entity = bus.session.declare_queryable(self.key, self._on_query)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._entity.undeclare()

    def _on_query(self, query) -> None:
        payload, signature = query_request(query)
        digest = request_digest(payload)
        try:
            with self._lock:
                req = self._gate.check(payload, signature, time.monotonic(),
                                       boot=self.bus.boot)
                if len(self._queue) >= MAX_PENDING:
                    raise ApplyRefused("too many zone applies waiting; ask again")
                self._queue.append((req, query, digest))
        except ApplyRefused as exc:
            operator = operator_of(payload, MAX_RESET_PAYLOAD)
            with self._lock:
                self.refused += 1
                self._refused.append(Alert(
                    REFUSED, "warning", f"zone apply in the name of {operator or '?'} refused: "
                    f"{exc}; the zones in force stay", "bus", time.monotonic(),
                    details={"operator": operator, "reason": str(exc)}))
            answer(self.bus, query, digest, {"accepted": False, "reason": str(exc),
                                             "operator": operator})
        except Exception:  # nothing a sender does may kill this callback
            answer(self.bus, query, digest, {"accepted": False,
                                             "reason": "malformed zone apply"})

    def take(self) -> tuple[list[tuple[ApplyRequest, object, str]], list[Alert]]:
        with self._lock:
            queued, refused = list(self._queue), list(self._refused)
            self._queue.clear()
            self._refused.clear()
        return queued, refused


def answer(bus, query, digest: str, body: dict) -> None:
    """Answer a zone-apply query (the request's SHA-256: ``digest``), signed by the monitor, and
    finalise it."""
    key = bus.keys.zones_apply
    with contextlib.suppress(Exception):
        payload, attachment = bus.signed_answer(key, {"schema": APPLY_ANSWER_SCHEMA, **body},
                                                digest)
        query.reply(key, payload, encoding="application/json", attachment=attachment)
    with contextlib.suppress(Exception):
        query.drop()


def _same_watch(a: list, b: list) -> bool:
    return len(a) == len(b) and all(
        ia == ib and pa.shape == pb.shape and np.array_equal(pa, pb)
        for (ia, pa), (ib, pb) in zip(a, b, strict=True))


class LiveZones:
    """The loop side: ``poll(now)`` applies (or refuses) the queued requests between steps."""

    def __init__(self, config, zones_file: str | None, pipeline, bus, applies: ZoneApplies,
                 alert: Callable[[Alert], None], log: Callable[..., None],
                 on_applied: Callable[[object], None] | None = None) -> None:
        self.config = config
        self.zones_file = zones_file
        self.pipeline = pipeline
        self.bus = bus
        self.applies = applies
        self.alert = alert
        self.log = log
        self.on_applied = on_applied  # the recorder and the feed's tool points
        self.last: dict | None = None

    @property
    def in_force(self) -> str:
        return self.pipeline.cell.config_hash if self.pipeline.cell is not None else ""

    def poll(self, now: float) -> None:
        queued, refused = self.applies.take()
        for alert in refused:
            self.alert(alert)
        for req, query, digest in queued:
            old = self.in_force
            try:
                new = self.apply(req)
            except ApplyRefused as exc:
                self.alert(Alert(REFUSED, "warning", f"zone apply by {req.operator} refused: "
                                 f"{exc}; the zones in force stay ({old[:12]})", "zones", now,
                                 details={"operator": req.operator, "reason": str(exc),
                                          "signed_hash": req.zones_hash, "in_force": old}))
                answer(self.bus, query, digest, {
                    "accepted": False, "reason": str(exc), "operator": req.operator,
                    "request_id": req.request_id, "config_hash": old})
                continue
            self.last = {"operator": req.operator, "old_hash": old, "new_hash": new,
                         "request_id": req.request_id, "note": req.note, "wall": time.time()}
            self.bus.update_status(zones_applied=self.last)
            self.alert(Alert(APPLIED, "warning", f"zone set {new[:12]} applied by "
                             f"{req.operator} (was {old[:12]}): STOP until every camera is "
                             "checked on it, then clear_time", "zones", now,
                             details=dict(self.last)))
            answer(self.bus, query, digest, {
                "accepted": True, "operator": req.operator, "request_id": req.request_id,
                "old_hash": old, "config_hash": new,
                "reason": f"zone set {new} in force; STOP until every camera has a frame on it, "
                          "then clear_time"})

    def apply(self, req: ApplyRequest) -> str:
        """Swap the zones when everything holds; ApplyRefused (nothing changed) otherwise."""
        from monitor.health.build import camera_health, protective_regions
        from monitor.health.references import choose_reference, load_chosen_reference
        from monitor.service.setup import prepared_zones, zone_checks
        from monitor.zones import load_cell, watch_regions

        if not self.zones_file:
            raise ApplyRefused("this monitor runs without a zone file ([zones] file): nothing "
                               "to apply")
        old_cell = self.pipeline.cell
        try:
            cell = load_cell(self.zones_file)
        except ConfigError as exc:
            raise ApplyRefused(f"the zone file is invalid: {_line(exc)}") from None
        except OSError as exc:
            raise ApplyRefused(f"cannot read the zone file: {exc}") from None
        draft = None  # the console's draft of an edit that weakens protection, if signed
        if cell.config_hash != req.zones_hash:
            draft = _draft_of(self.zones_file, req.zones_hash)
            if draft is None:
                raise ApplyRefused(f"the file changed after you signed: you signed "
                                   f"{req.zones_hash[:12]}, {self.zones_file} has "
                                   f"{cell.config_hash[:12]} now")
            cell = draft
        if cell.config_hash == self.in_force:
            raise ApplyRefused(f"zone set {cell.config_hash[:12]} is already in force")
        try:
            zone_checks(self.config, cell, self.zones_file)
            for cam in self.config.cameras:
                was = old_cell.cameras.get(cam.id) if old_cell is not None else None
                now = cell.cameras[cam.id]
                if was is not None and (was.width, was.height) != (now.width, now.height):
                    raise ConfigError(f"camera {cam.id!r} changes size ({was.width}x"
                                      f"{was.height} -> {now.width}x{now.height}): restart the "
                                      "service for that")
            health = {}
            for cam in self.config.cameras:
                watch = watch_regions(cell, cam.id)
                choice = choose_reference(cam.id, cam.reference, cell)
                if old_cell is not None and _same_watch(watch, watch_regions(old_cell, cam.id)) \
                        and _same_watch(protective_regions(cell, [cam.id])[cam.id],
                                        protective_regions(old_cell, [cam.id])[cam.id]) \
                        and choice == choose_reference(cam.id, cam.reference, old_cell):
                    continue  # the health checker keeps what it learned
                if self.pipeline.cameras[cam.id].health is None:
                    continue
                reference = load_chosen_reference(choice, cell)
                envelope = self.pipeline.cameras[cam.id].health.envelope
                health[cam.id] = camera_health(self.config.health, cam.id, reference, cell,
                                               envelope)
            prepared = prepared_zones(self.config, cell)
        except (ConfigError, InputError) as exc:  # InputError: a reference image missing
            raise ApplyRefused(f"the zone file is refused: {_line(exc)}") from None
        if draft is not None:
            # the signed draft becomes the zone file (a restart then loads what was signed),
            # and only now: a refused apply leaves both files as they were
            try:
                cell = promote_draft(self.zones_file, req.zones_hash)
            except ConfigError as exc:
                raise ApplyRefused(f"the draft cannot become the zone file: {_line(exc)}") \
                    from None
            self.log("zone draft promoted", operator=req.operator, file=self.zones_file,
                     new_hash=cell.config_hash)
        self.pipeline.swap_cell(cell, prepared, health, note=f" by {req.operator}")
        self.bus.set_config_hash(cell.config_hash)
        if self.on_applied is not None:
            with contextlib.suppress(Exception):  # extras (the recorder) never refuse it
                self.on_applied(cell)
        self.log("zones applied", operator=req.operator, old_hash=old_cell.config_hash
                 if old_cell is not None else "", new_hash=cell.config_hash,
                 request_id=req.request_id)
        return cell.config_hash


def _draft_of(zones_file: str, signed: str):
    """The draft beside ``zones_file`` when its zone set is ``signed`` (else None)."""
    from monitor.zones import load_cell

    draft = draft_path(zones_file)
    try:
        cell = load_cell(draft) if draft.is_file() else None
    except (ConfigError, OSError):
        return None
    return cell if cell is not None and cell.config_hash == signed else None


def _line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
