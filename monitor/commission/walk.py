"""The walk test's analysis: per-step decisions of a walk through the cell -> per zone, the floor
cells the person was seen in, the blind spots, every entry with its time to STOP, and the gaps
in detection. Pure (``WalkRecorder`` only collects what the pipeline decided).

* **seen cells**: floor cells (``floor.ZoneFloor``) under the bottom centre of a detected,
  unmasked person's box in some frame; **visible cells**: the cells a camera can see a person
  in at all (``zones.visibility``); **blind spots**: the zone's cells no camera sees.
* **entry**: the first frame in which the person is in the zone: a zone hit of the zone check,
  or a detected foot point on the zone's floor, whichever comes first, after a frame without.
  Its **time to STOP** is the time from that frame to the first decision (frame or timer tick)
  whose command is STOP and names the zone (a warning zone: SLOW naming it, or any STOP);
  ``None`` when none came before the person left. An entry while an earlier STOP still holds
  counts from the first decision that names this zone.
* **gap**: frames between two detections of a person (from the first detection to the last)
  with nobody detected, longer than 1.5 frame intervals; it belongs to the zones the person
  was last seen in.
"""

from __future__ import annotations

import itertools
import statistics
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from monitor.commission.floor import ZoneFloor, feet_on_floor
from monitor.policy import SLOW, STOP
from monitor.zones import Cell

GAP_FACTOR = 1.5  # a gap is longer than this many frame intervals


@dataclass(frozen=True)
class StepSample:
    """What the walk keeps of one decision."""

    time_s: float
    frame: bool  # False: a timer tick between two frames
    state: str
    named_zones: tuple[str, ...]  # zones the command's reasons name
    hit_zones: tuple[str, ...] = ()  # zones the zone check found a seen person in
    persons: int = 0  # persons detected and not masked in this frame
    feet_m: tuple[tuple[float, float], ...] = ()  # their floor points


@dataclass(frozen=True)
class Entry:
    entry_s: float
    exit_s: float | None  # None: still inside at the end of the walk
    stop_s: float | None
    time_to_stop_s: float | None
    frames_inside: int


@dataclass(frozen=True)
class Gap:
    from_s: float  # last frame with a detection before the gap
    to_s: float  # next frame with a detection
    duration_s: float
    frames_missed: int
    last_seen_m: tuple[float, float] | None


@dataclass(frozen=True)
class ZoneWalk:
    zone_id: str
    kind: str
    cells: int  # floor cells of the zone (0: an image zone, no floor)
    visible_cells: int
    seen_cells: int
    blind_spots: tuple[tuple[float, float], ...]  # centres of the cells no camera sees
    unvisited: tuple[tuple[float, float], ...]  # visible cells the walk never saw a person in
    entries: tuple[Entry, ...]
    gaps: tuple[Gap, ...]

    @property
    def visible_fraction(self) -> float | None:
        return self.visible_cells / self.cells if self.cells else None

    @property
    def seen_fraction(self) -> float | None:
        return self.seen_cells / self.cells if self.cells else None


@dataclass(frozen=True)
class WalkResult:
    duration_s: float
    frames: int
    frame_interval_s: float
    cell_m: float
    zones: tuple[ZoneWalk, ...]
    gaps: tuple[Gap, ...]
    seen_m: tuple[tuple[float, float], ...] = field(default=(), repr=False)

    def to_dict(self) -> dict:
        """JSON of the result (numbers rounded: the same walk gives the same text)."""
        return _rounded({
            "duration_s": self.duration_s, "frames": self.frames,
            "frame_interval_s": self.frame_interval_s, "cell_m": self.cell_m,
            "zones": [{**asdict(z), "visible_fraction": z.visible_fraction,
                       "seen_fraction": z.seen_fraction} for z in self.zones],
            "gaps": [asdict(g) for g in self.gaps],
            "seen_m": list(self.seen_m)})

    def zone(self, zone_id: str) -> ZoneWalk:
        return next(z for z in self.zones if z.zone_id == zone_id)


class WalkRecorder:
    """A driver sink (or replay ``publish`` callback) that keeps a ``StepSample`` per step."""

    def __init__(self, cell: Cell) -> None:
        self.cell = cell
        self.samples: list[StepSample] = []

    def __call__(self, result) -> None:
        cmd = result.command
        named = tuple(sorted({r.zone_id for r in cmd.reasons if r.zone_id}))
        frame = result.frame
        if frame is None or result.persons is None:
            self.samples.append(StepSample(result.now, frame is not None, cmd.state, named))
            return
        report = result.zone_report
        hits = tuple(sorted({h.zone_id for h in report.hits if not h.lost})) \
            if report is not None else ()
        masked = set(report.masked) if report is not None else set()
        rows = [i for i in range(len(result.persons)) if i not in masked]
        boxes = result.persons.boxes_px[rows]
        feet = feet_on_floor(self.cell, frame.camera_id, boxes, frame.width, frame.height)
        self.samples.append(StepSample(
            result.now, True, cmd.state, named, hits, len(rows),
            tuple((float(x), float(y)) for x, y in feet)))


def analyse(samples: Sequence[StepSample], floors: Sequence[ZoneFloor],
            alarm_zones: Sequence[tuple[str, str]] = ()) -> WalkResult:
    """The walk's result. ``floors``: the volume zones' floor grids; ``alarm_zones``: (id,
    kind) of image-polygon protective/warning zones (entries only, no floor)."""
    frames = [s for s in samples if s.frame]
    times = [s.time_s for s in frames]
    interval = statistics.median(np.diff(times)) if len(times) >= 2 else 0.0
    gaps = _gaps(frames, interval)
    seen = np.array([p for s in frames for p in s.feet_m], float).reshape(-1, 2)
    zones = []
    for f in floors:
        inside = [(bool(s.feet_m) and bool((f.cell_of(np.array(s.feet_m)) >= 0).any()))
                  or f.zone_id in s.hit_zones for s in frames]
        zones.append(_zone(samples, frames, inside, f.zone_id, f.kind, gaps, f))
    for zone_id, kind in alarm_zones:
        inside = [zone_id in s.hit_zones for s in frames]
        zones.append(_zone(samples, frames, inside, zone_id, kind, gaps, None))
    duration = (times[-1] - times[0] + interval) if times else 0.0
    return WalkResult(duration, len(frames), interval, floors[0].cell_m if floors else 0.0,
                      tuple(zones), gaps, tuple(map(tuple, seen.tolist())))


def _zone(samples: Sequence[StepSample], frames: Sequence[StepSample], inside: list[bool],
          zone_id: str, kind: str, gaps: tuple[Gap, ...], floor: ZoneFloor | None) -> ZoneWalk:
    entries = _entries(samples, frames, inside, zone_id, kind)
    own_gaps = tuple(g for g in gaps if _gap_in(g, frames, inside))
    if floor is None:
        return ZoneWalk(zone_id, kind, 0, 0, 0, (), (), entries, own_gaps)
    seen = np.zeros(len(floor.centres_m), dtype=bool)
    for s in frames:
        k = floor.cell_of(np.array(s.feet_m)) if s.feet_m else np.zeros(0, int)
        seen[k[k >= 0]] = True
    blind = floor.centres_m[~floor.visible]
    unvisited = floor.centres_m[floor.visible & ~seen]
    return ZoneWalk(zone_id, kind, len(floor.centres_m), int(floor.visible.sum()),
                    int(seen.sum()), _points(blind), _points(unvisited), entries, own_gaps)


def _entries(samples: Sequence[StepSample], frames: Sequence[StepSample], inside: list[bool],
             zone_id: str, kind: str) -> tuple[Entry, ...]:
    out = []
    k = 0
    while k < len(frames):
        if not inside[k]:
            k += 1
            continue
        start = k
        while k < len(frames) and inside[k]:
            k += 1
        t_in = frames[start].time_s
        t_out = frames[k].time_s if k < len(frames) else None
        stop = next((s.time_s for s in samples if s.time_s >= t_in - 1e-9
                     and (t_out is None or s.time_s < t_out) and _answers(s, zone_id, kind)),
                    None)
        out.append(Entry(t_in, t_out, stop, None if stop is None else stop - t_in, k - start))
    return tuple(out)


def _answers(s: StepSample, zone_id: str, kind: str) -> bool:
    """The decision answers a person in the zone: a STOP naming a protective zone; for a
    warning zone a SLOW naming it, or any STOP (the robot is stopped already)."""
    if kind == "protective":
        return s.state == STOP and zone_id in s.named_zones
    return s.state == STOP or (s.state == SLOW and zone_id in s.named_zones)


def _gaps(frames: Sequence[StepSample], interval: float) -> tuple[Gap, ...]:
    seen = [i for i, s in enumerate(frames) if s.persons > 0]
    out = []
    for a, b in itertools.pairwise(seen):
        dt = frames[b].time_s - frames[a].time_s
        if b - a > 1 and dt > GAP_FACTOR * interval:
            last = frames[a].feet_m[0] if frames[a].feet_m else None
            out.append(Gap(frames[a].time_s, frames[b].time_s, dt, b - a - 1, last))
    return tuple(out)


def _gap_in(gap: Gap, frames: Sequence[StepSample], inside: list[bool]) -> bool:
    """The person was in the zone in the last frame before the gap or the first after it."""
    return any(s.time_s in (gap.from_s, gap.to_s) and inside[i]
               for i, s in enumerate(frames))


def _points(a: np.ndarray) -> tuple[tuple[float, float], ...]:
    return tuple((round(float(x), 3), round(float(y), 3)) for x, y in a)


def _rounded(value):
    if isinstance(value, float):
        return round(value, 4)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_rounded(v) for v in value]
    return value
