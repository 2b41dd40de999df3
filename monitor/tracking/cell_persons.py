"""One person id across the cameras of a cell: a camera's track becomes a *cell person*.

Each camera numbers its own tracks (``monitor.tracking.tracks.PersonTracker``): cam0's person 1 and
cam1's person 4 may be one human standing where both views overlap. Reasons, holds, alerts, the
log and the annotated video name persons by their cell person id instead:

* a camera track seen for the first time, placed on the cell floor (a calibrated camera), is
  linked to the cell person another camera placed within ``link_m`` of it at nearly the same
  time (``link_s``; the other placement moved by its floor velocity to this frame's time), the
  nearest when several are that close, and that guess is said once ("seen again as person 7?");
  otherwise it is a new cell person (1, 2, 3, ... for the whole cell);
* once named, a track keeps its cell id for its life (until its tracker forgets it), so a
  person walking around keeps one id; a cell person is never linked to a second track of a
  camera that already has one of theirs (two tracks of one camera are two persons);
* a track of a camera without calibration (no floor) keeps its camera's id, qualified with the
  camera when the cell has several (``person cam1:4``), so two cameras never give one bare
  number to two persons. With one camera every id is the tracker's own.

Names only: a link never ends a hold nor merges two cameras' zone answers (every hit stays,
merged towards danger), so a wrong link (persons closer than ``link_m`` may swap ids) can
mislabel a reason but never clear a zone. Deterministic: times are passed in.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Annotated

import numpy as np
from pydantic import Field

from monitor.schema import Float, section
from monitor.tracking.tracks import Hold, PersonTracker, Track, TrackUpdate
from monitor.types import ZoneReport

Who = int | str  # a cell person id, or a camera-qualified track id ("cam1:4")


@section("tracking")
class CellPersonsConfig:
    """How tracks of different cameras are linked into one cell person (docs/tracking.md)."""

    link_m: Annotated[Float, Field(gt=0, le=3.0, description=(
        "a camera's new track is the person another camera placed within this many metres "
        "on the floor; persons standing closer than this may swap ids"))] = 0.6
    link_s: Annotated[Float, Field(gt=0, le=5.0, description=(
        "... at most this many seconds apart (the cameras' frames come in turn)"))] = 0.5


@dataclass(frozen=True)
class Named:
    """One camera frame's tracks in cell persons."""

    person_ids: tuple[Who, ...]  # per row of the frame's Persons
    report: ZoneReport | None  # every hit with ``who`` set
    lines: tuple[str, ...] = ()  # to log: holds begun, re-identifications, guessed links


@dataclass
class _Placed:
    floor: np.ndarray  # (2,) metres
    velocity: np.ndarray | None  # (2,) m/s
    time: float


@dataclass
class CellPersons:
    """The cell persons of one monitor's cameras (one per pipeline)."""

    camera_ids: tuple[str, ...]
    config: CellPersonsConfig = field(default_factory=CellPersonsConfig)
    _who: dict[tuple[str, int], Who] = field(default_factory=dict)
    _placed: dict[tuple[str, int], _Placed] = field(default_factory=dict)
    _next: int = 1

    def who(self, camera_id: str, track_id: int) -> Who:
        """The cell person of a camera's track (its camera-qualified id when unnamed)."""
        got = self._who.get((camera_id, track_id))
        if got is not None:
            return got
        return track_id if len(self.camera_ids) <= 1 else f"{camera_id}:{track_id}"

    def hold(self, camera_id: str, hold: Hold) -> Hold:
        """The hold with its person (and the one perhaps seen again) as cell persons."""
        seen = None if hold.seen_as is None else self.who(camera_id, hold.seen_as)
        return replace(hold, who=self.who(camera_id, hold.track_id), seen_as=seen)

    # ---------------------------------------------------------------------------------------
    def name(self, camera_id: str, tracker: PersonTracker, update: TrackUpdate, now: float
             ) -> Named:
        """Name this frame's tracks of ``camera_id`` (after ``tracker.update``) and its zone
        report's hits; ``now`` is the frame's capture time."""
        lines = list(self.update(camera_id, tracker.tracks, update.track_ids, now,
                                 calibrated=tracker.to_floor is not None))
        lines += [self.hold(camera_id, h).describe() for h in update.started]
        rules = dict(update.ended_by)
        lines += [f"hold of person {self.hold(camera_id, h).who} ended "
                  f"({rules.get(h.track_id, 'seen free')})" for h in update.ended]
        for new, old in update.reidentified:  # a guess: said, the hold stays
            n, o = self.who(camera_id, new), self.who(camera_id, old)
            lines.append(f"person {n} (was person {o}?) seen near where person {o} was lost; "
                         f"that hold stays until person {o} is seen leaving or a confirm-clear "
                         "reset")
        report = update.report
        if report is not None:
            report = replace(report, hits=tuple(
                h if h.track_id is None else replace(h, who=self.who(camera_id, h.track_id))
                for h in report.hits))
        ids = tuple(self.who(camera_id, t) for t in update.track_ids)
        return Named(ids, report, tuple(lines))

    def update(self, camera_id: str, tracks: Sequence[Track], seen: Sequence[int], now: float,
               calibrated: bool = True) -> tuple[str, ...]:
        """Take a camera's tracks after its frame at ``now`` (``seen``: the track ids of its
        rows): forget tracks its tracker forgot, note where the seen ones stand, name the new
        ones. Returns what to say of guessed links."""
        alive = {t.track_id for t in tracks}
        for key in [k for k in self._who if k[0] == camera_id and k[1] not in alive]:
            self._who.pop(key)
            self._placed.pop(key, None)
        seen_set = set(seen)
        new: list[Track] = []
        for t in sorted(tracks, key=lambda t: t.track_id):
            if t.track_id not in seen_set:
                continue
            key = (camera_id, t.track_id)
            if t.floor_m is not None:
                v = None if t.floor_velocity_mps is None else np.array(t.floor_velocity_mps)
                self._placed[key] = _Placed(np.array(t.floor_m, np.float64), v, now)
            else:
                self._placed.pop(key, None)
            if key not in self._who:
                new.append(t)
        if not new:
            return ()
        if len(self.camera_ids) <= 1:
            self._who.update(((camera_id, t.track_id), t.track_id) for t in new)
            return ()
        if not calibrated:
            self._who.update(((camera_id, t.track_id), f"{camera_id}:{t.track_id}")
                             for t in new)
            return ()
        return self._link(camera_id, [t for t in new if t.floor_m is not None], now) \
            + self._start(camera_id, [t for t in new if t.floor_m is None])

    def _start(self, camera_id: str, tracks: Sequence[Track]) -> tuple[str, ...]:
        for t in tracks:
            self._who[(camera_id, t.track_id)] = self._next
            self._next += 1
        return ()

    def _link(self, camera_id: str, tracks: list[Track], now: float) -> tuple[str, ...]:
        """Nearest pairs first, each new track and each cell person used once; the rest are
        new cell persons."""
        cfg = self.config
        taken = {w for (cam, _), w in self._who.items() if cam == camera_id}
        pairs: list[tuple[float, int, Who]] = []
        for row, t in enumerate(tracks):
            here = np.array(t.floor_m, np.float64)
            near: dict[Who, float] = {}  # cell person -> distance from this track
            for (cam, tid), placed in self._placed.items():
                who = self._who.get((cam, tid))
                dt = now - placed.time
                if cam == camera_id or who is None or who in taken or not abs(dt) <= cfg.link_s:
                    continue
                there = placed.floor if placed.velocity is None else \
                    placed.floor + placed.velocity * dt  # where they are by now
                d = float(np.linalg.norm(here - there))
                if d <= cfg.link_m and d < near.get(who, np.inf):
                    near[who] = d
            pairs += [(d, row, who) for who, d in near.items()]
        said: list[str] = []
        linked: dict[int, Who] = {}
        used: set[Who] = set()
        for d, row, who in sorted(pairs, key=lambda p: (p[0], p[1], str(p[2]))):
            if row in linked or who in used:
                continue
            linked[row] = who
            used.add(who)
            others = [str(w) for w in sorted({w for _, r, w in pairs if r == row and w != who},
                                             key=lambda w: (isinstance(w, str), str(w).zfill(9)))]
            if others:  # a guess: the nearest taken, said once (when the track is named)
                tid = tracks[row].track_id
                said.append(f"track {tid} seen again as person {who}? (persons "
                            f"{', '.join([str(who), *others])} within {cfg.link_m} m of it on "
                            f"the floor; the nearest ({d:.2f} m) taken)")
        for row, t in enumerate(tracks):
            if row in linked:
                self._who[(camera_id, t.track_id)] = linked[row]
            else:
                self._start(camera_id, [t])
        return tuple(said)
