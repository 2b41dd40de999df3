"""Hand-over of holds between the monitors of one cell (issue 24; docs/consumer.md).

A person tracked by monitor-a who walks out of its camera's view (a *departure*: the box at the
image edge, moving outwards), is lost anywhere else outside its zones ("lost": behind a
fixture, at the far end of the view) or is lost inside one of its zones (a *hold*) may be where
only monitor-b's zones are, unseen by monitor-b's cameras (hidden, missed). Each monitor with
peers publishes the list of its holds and recent losses (``entries_of``; signed on its
``safety/<role>/holds`` key, ``monitor.bus.holds``); a receiving monitor turns each verified
entry it has not taken before into a hold of its own (``HandedHolds``): a ``person_lost`` STOP
on every protective zone of its own whose floor footprint lies within reach of the entry's floor
point (walking speed x ``reach_s``), and on any of its protective zones with an id the entry
held. A held zone ends when its own cameras see a person within reach of that point *inside
that zone* (whose own hits then keep it occupied), or on an operator's confirm-clear reset. A
peer that falls silent never ends one (``monitor.bus.holds`` makes the silence a STOP); a peer
message with more persons than ``MAX_ENTRIES`` holds every protective zone.

Pure: no clock, no I/O; the edges pass times in.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Annotated, Any

import numpy as np
from pydantic import Field

from monitor.schema import ConfigPath, Float, section
from monitor.types import Fault, ZoneHit, ZoneReport
from monitor.wire.busconfig import Role
from monitor.zones.draw import volume_outline_m
from monitor.zones.moving import follows_tool

HANDOVER_SCHEMA = "workcell.safety.holds/1"
MAX_ENTRIES = 64  # per message: a flood cannot grow a receiver's memory without bound
KINDS = ("hold", "departure", "lost")  # entry kinds on the wire ("overflow": receiver only)
MAX_TAKEN = 4096  # remembered (role, boot, person) keys: the oldest are forgotten first
# handed-over hits: person indices far below any camera's lost-person index
_PERSON_BASE = -1_000_000


@section("handover")
class HandoverConfig:
    """Holds handed over between the monitors of one cell (docs/consumer.md)."""

    # role -> the public key file of each peer monitor whose holds this monitor takes
    # (e.g. "monitor-b" = "keys/monitor-b.key.pub"); empty: no hand-over (nothing published)
    peers: dict[Role, ConfigPath] = field(default_factory=dict)
    # a person this monitor lost outside its zones is handed over this long after the last sight
    keep_s: Annotated[Float, Field(gt=0, le=60)] = 5.0
    # a handed-over point reaches the zones a person walks to in this many seconds
    reach_s: Annotated[Float, Field(gt=0, le=10)] = 1.0
    # no valid holds message from a peer for this long: a STOP (``handover_silent``)
    peer_timeout_s: Annotated[Float, Field(gt=0, le=10)] = 1.0


@dataclass(frozen=True)
class Entry:
    """One person handed over: ``kind`` "hold" (lost inside ``zones``), "departure" (left
    the view at an image edge) or "lost" (lost anywhere else: behind a fixture, at the far end
    of the view); ``floor_m`` the last floor point (cell metres); ``wall`` the sender's Unix
    time of the last sighting; ``seen`` the same in the sender's own clock (it names one loss
    of the person: a person lost again later is a new entry)."""

    person: int
    kind: str
    floor_m: tuple[float, float]
    wall: float
    zones: tuple[str, ...] = ()
    camera: str = ""
    seen: float | None = None

    def to_dict(self) -> dict:
        return {"person": self.person, "kind": self.kind,
                "floor_m": [round(self.floor_m[0], 3), round(self.floor_m[1], 3)],
                "wall": self.wall, "zones": list(self.zones), "camera": self.camera,
                **({} if self.seen is None else {"seen": self.seen})}

    @classmethod
    def from_dict(cls, d: Any) -> Entry:
        """An entry from a verified message; ValueError when malformed."""
        if not isinstance(d, dict):
            raise ValueError("an entry must be an object")
        person, kind, floor, wall = d.get("person"), d.get("kind"), d.get("floor_m"), \
            d.get("wall")
        zones, camera, seen = d.get("zones", []), d.get("camera", ""), d.get("seen")
        if not isinstance(person, int) or isinstance(person, bool) or kind not in KINDS:
            raise ValueError("entry: person (integer) and kind (hold, departure or lost)")
        if seen is not None and not (isinstance(seen, int | float) and not isinstance(
                seen, bool) and math.isfinite(seen)):
            raise ValueError("entry: seen is a time")
        if not (isinstance(floor, list) and len(floor) == 2 and all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in floor)):
            raise ValueError("entry: floor_m is [x, y] in metres")
        if not isinstance(wall, int | float) or isinstance(wall, bool) or not math.isfinite(
                wall):
            raise ValueError("entry: wall is a Unix time")
        if not isinstance(zones, list) or not all(isinstance(z, str) for z in zones) \
                or not isinstance(camera, str):
            raise ValueError("entry: zones is a list of zone ids, camera a string")
        return cls(person, kind, (float(floor[0]), float(floor[1])), float(wall),
                   tuple(zones), camera, None if seen is None else float(seen))


def entries_of(tracks: Mapping[str, Sequence[Any]], now: float, wall_now: float,
               keep_s: float) -> tuple[Entry, ...]:
    """What this monitor hands over now, from each camera's tracks
    (``monitor.tracking.tracks.Track``): every lost person holding zones, and every other person
    lost within ``keep_s`` -- one who left the view at an image edge ("departure") or was lost
    anywhere else ("lost": behind a fixture, at the far end of the view, where only a peer's zone
    may be). ``now`` is the tracks' clock, ``wall_now`` the Unix time at ``now``. Holds first, then
    the most recent. A track without a finite floor point (uncalibrated camera) cannot be handed
    over. All of them: ``holds_payload`` says when there are more than a message carries."""
    out = []
    for cid, camera_tracks in sorted(tracks.items()):
        for t in camera_tracks:
            if not t.lost or t.floor_m is None or not all(map(math.isfinite, t.floor_m)):
                continue
            age = max(0.0, now - t.last_seen)
            if t.held:
                kind = "hold"
            elif age <= keep_s:
                kind = "departure" if getattr(t, "left_view", False) else "lost"
            else:
                continue
            out.append(Entry(t.track_id, kind, t.floor_m, wall_now - age,
                             tuple(z.zone_id for z in t.held), cid, float(t.last_seen)))
    out.sort(key=lambda e: (e.kind != "hold", -e.wall))
    return tuple(out)


def overflow_entry(count: int, wall: float) -> Entry:
    """The receiver's stand-in for a peer message with more persons than ``MAX_ENTRIES``: the
    ones left off could be anywhere, so it reaches every protective zone."""
    return Entry(-1, "overflow", (0.0, 0.0), wall, (), f"{count} persons")


def silent_peers(heard: Mapping[str, float | None], started: float, now: float,
                 timeout_s: float, keep_s: float, refused: str = "") -> tuple[Fault, ...]:
    """A ``handover_silent`` STOP per peer role with no valid holds message for over
    ``timeout_s`` (``heard``: role -> my clock at its last accepted message, None: none since
    ``started``). A peer whose clock is off by more than the window, whose messages are all
    malformed, forged or never sent is silent: what it hands over would be lost, so the cell
    may not RUN on it. Latched once a peer that was heard stays silent past ``keep_s``: its
    entries of that time are gone, a person it lost then is nowhere held; a peer never heard
    since start (a cell starting up) does not latch."""
    out = []
    for role in sorted(heard):
        last = heard[role]
        silent = now - (started if last is None else last)
        if not silent <= timeout_s:  # NaN: silent
            why = f" (refused: {refused})" if refused else ""
            out.append(Fault("handover_silent", f"no valid holds message from {role} for "
                             f"{silent:.1f} s{why}: persons it hands over would be lost",
                             True, "handover", latch=last is not None and silent > keep_s))
    return tuple(out)


# ---------------------------------------------------------------------------------------------
# which of my zones an entry reaches


def distance_to_polygon(point: tuple[float, float], polygon: np.ndarray) -> float:
    """Metres from ``point`` to the polygon (M, 2) on the floor; 0 inside or on it."""
    p = np.asarray(point, float)
    poly = np.asarray(polygon, float).reshape(-1, 2)
    if len(poly) == 0:
        return math.inf
    if len(poly) >= 3 and _inside(p, poly):
        return 0.0
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    length2 = np.maximum((ab ** 2).sum(axis=1), 1e-12)
    t = np.clip(((p - a) * ab).sum(axis=1) / length2, 0.0, 1.0)
    nearest = a + t[:, None] * ab
    return float(np.min(np.linalg.norm(nearest - p, axis=1)))


def _inside(p: np.ndarray, poly: np.ndarray) -> bool:
    x, y = p
    inside = False
    for (x1, y1), (x2, y2) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def zone_footprints(cell: Any) -> dict[str, np.ndarray]:
    """Zone id -> floor footprint (M, 2) metres of each enabled protective zone of ``cell``:
    a volume's outline at its floor, a mesh's bounding box, an image polygon mapped to the
    floor through its camera's calibration. A zone with no footprint (a polygon of an
    uncalibrated camera, a zone that follows the tool) is reached only by its id."""
    out: dict[str, np.ndarray] = {}
    for z in getattr(cell, "zones", ()):
        if not (z.enabled and z.kind == "protective") or follows_tool(z):
            continue
        try:
            if getattr(z, "shape", "") == "polygon":
                model = cell.camera_models.get(z.camera)
                if model is None:
                    continue
                xy, ok = model.pixel_to_floor(np.asarray(z.points_px, float))
                if not np.all(ok):  # a corner above the horizon: no floor outline
                    continue
                out[z.id] = np.asarray(xy, float)
            elif getattr(z, "shape", "") == "mesh":
                verts = cell.meshes[z.id][0]
                lo, hi = verts.min(axis=0), verts.max(axis=0)
                out[z.id] = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]],
                                      [lo[0], hi[1]]])
            else:
                out[z.id] = np.asarray(volume_outline_m(z, cell)[0], float)[:, :2]
        except Exception:
            continue
    return out


def protective_ids(cell: Any) -> frozenset[str]:
    """The ids of every enabled protective zone of ``cell``, with or without a footprint."""
    return frozenset(z.id for z in getattr(cell, "zones", ())
                     if z.enabled and z.kind == "protective")


def reached_zones(entry: Entry, footprints: Mapping[str, np.ndarray], reach_m: float,
                  protective: Iterable[str] = ()) -> tuple[str, ...]:
    """My protective zones the entry's person may be in: footprints within ``reach_m`` of its
    floor point, and zones with an id it held (the same zone seen from both sides), footprint
    or not (``protective``: every protective zone id; a zone that follows the tool has none).
    An overflow entry reaches every one of them."""
    ids = set(footprints) | set(protective)
    if entry.kind == "overflow":
        return tuple(sorted(ids))
    near = {zid for zid, poly in footprints.items()
            if distance_to_polygon(entry.floor_m, poly) <= reach_m}
    same = {zid for zid in entry.zones if zid in ids}
    return tuple(sorted(near | same))


# ---------------------------------------------------------------------------------------------
# the holds a monitor took from its peers


@dataclass(frozen=True)
class HandedHold:
    """A peer's person held on my zones (``since``: my clock, when the peer last saw them)."""

    role: str
    boot: str
    entry: Entry
    zones: tuple[str, ...]
    since: float
    serial: int

    def describe(self, when: Any = None, zones: Sequence[str] | None = None) -> str:
        """``person 3 of monitor-a left its view toward cam1-stop at 12:00:03 (handed
        over)``; ``when`` formats ``since`` (None: no time, a log line carries its own)."""
        names = ", ".join(self.zones if zones is None else zones)
        at = "" if when is None else f" at {when(self.since)}"
        if self.entry.kind == "overflow":
            return (f"{self.role} handed over more persons than a message carries "
                    f"({self.entry.camera}): every protective zone held: {names}{at}")
        verb = "left its view toward" if self.entry.kind == "departure" else \
            "was lost near"
        return f"person {self.entry.person} of {self.role} {verb} {names}{at} (handed over)"


@dataclass
class HandedHolds:
    """The holds taken from peers (one per (role, boot, person), never taken twice) and their
    lost hits for every decision. Not thread-safe: the loop's thread only."""

    walk_speed_mps: float = 1.5
    reach_s: float = 1.0
    when: Any = None  # formats a time in reason texts (None: no time)
    _holds: list[HandedHold] = field(default_factory=list)
    _taken: dict[tuple[str, str, int, float | None], None] = field(default_factory=dict)
    _serial: int = 0

    @property
    def reach_m(self) -> float:
        return self.walk_speed_mps * self.reach_s

    @property
    def holds(self) -> tuple[HandedHold, ...]:
        return tuple(self._holds)

    def take(self, role: str, boot: str, entries: Iterable[Entry], cell: Any, now: float,
             wall_now: float) -> tuple[HandedHold, ...]:
        """Verified entries of peer ``role`` (its ``boot``): each not taken before becomes a
        hold on the zones of ``cell`` it reaches (none reached: nothing held, remembered as
        taken). ``now``/``wall_now``: my clock and Unix time now. Returns the new holds."""
        footprints = zone_footprints(cell) if cell is not None else {}
        protective = protective_ids(cell) if cell is not None else frozenset()
        new = []
        for entry in entries:
            if entry.kind == "overflow":
                # held while the peer overflows: taken again after a confirm-clear
                if any(h.role == role and h.entry.kind == "overflow" for h in self._holds):
                    continue
            else:
                # one loss of one person (``seen``): a person lost again later is new
                key = (role, boot, entry.person, entry.seen)
                if key in self._taken:
                    continue
                self._taken[key] = None
                while len(self._taken) > MAX_TAKEN:
                    del self._taken[next(iter(self._taken))]
            zones = reached_zones(entry, footprints, self.reach_m, protective)
            if not zones:
                continue
            self._serial += 1
            since = now - max(0.0, wall_now - entry.wall)
            hold = HandedHold(role, boot, entry, zones, since, self._serial)
            self._holds.append(hold)
            new.append(hold)
        return tuple(new)

    def release_seen(self, seen: Iterable[tuple[tuple[float, float] | None, Iterable[str]]]
                     ) -> tuple[HandedHold, ...]:
        """Persons my cameras see now, each (floor point, ids of the zones they are in): a
        held zone ends when a person within reach of the hold's point is seen *inside it*
        (their own hits keep it occupied from now on); the hold ends with its last zone. A
        person seen near the point but outside the zone ends nothing: the handed-over person
        may be the one my cameras do not see, inside it. Returns the holds ended."""
        people = [(np.asarray(p, float), frozenset(z)) for p, z in seen if p is not None]
        if not people or not self._holds:
            return ()
        ended, kept = [], []
        for h in self._holds:
            point = np.asarray(h.entry.floor_m, float)
            inside = set().union(*(z for p, z in people if h.entry.kind != "overflow"
                                   and float(np.linalg.norm(p - point)) <= self.reach_m))
            left = tuple(z for z in h.zones if z not in inside)
            if not left:
                ended.append(h)
            else:
                kept.append(h if left == h.zones else replace(h, zones=left))
        self._holds = kept
        return tuple(ended)

    def drop(self) -> tuple[HandedHold, ...]:
        """An operator confirmed the cell clear: every handed-over hold ends."""
        dropped, self._holds = tuple(self._holds), []
        return dropped

    def report(self) -> ZoneReport | None:
        """One ``lost`` protective hit per held zone (None: no hold)."""
        if not self._holds:
            return None
        return ZoneReport(hits=tuple(
            ZoneHit(zid, "protective", _PERSON_BASE - h.serial, 0.0, None, h.entry.person,
                    True, h.since, note=h.describe(self.when, (zid,)))
            for h in self._holds for zid in h.zones))

    def decide(self, trackers: Iterable[Any]) -> ZoneReport | None:
        """At a decision: holds whose point my cameras now see a person near end, then the
        lost hits of the rest (``trackers``: each camera's ``PersonTracker``)."""
        self.release_seen((t.floor_m, [z.zone_id for z in t.zones]) for tr in trackers
                          for t in tr.tracks if not t.lost and t.floor_m is not None)
        return self.report()
