"""The walk test's analysis: per-step decisions of a walk through the cell -> per zone, the floor
cells the person was seen in, the blind spots, every entry with its time to STOP, and the gaps
in detection. Pure (``WalkRecorder`` only collects what the pipeline decided).

* **seen cells**: floor cells (``floor.ZoneFloor``) under the bottom centre of a detected,
  unmasked person's box in some frame; **visible cells**: the cells a camera can see a person
  in at all (``zones.visibility``); **blind spots**: the zone's cells no camera sees.
* **entry**: the first frame in which the person is in the zone: a zone hit of the zone check,
  a detected foot point on the zone's floor, or, with the walk's ground truth
  (``monitor.commission.truth``: a generated walk), a person truly standing on the zone's
  floor, whichever comes first, after a frame without. Its **time to STOP** is the video time
  from that frame to the first decision (frame or timer tick) whose command is STOP and names
  the zone (a warning zone: SLOW naming it, or any STOP); ``None`` when none came before the
  person left. Without ground truth the entry is the first detection in the zone, and since
  the policy stops on the first step that shows the cause, that is 0 unless the zone check
  needed more than the detection; with it, a detector that misses the person in their first
  frame inside shows one frame interval. An entry while an earlier STOP still holds counts
  from the first decision that names this zone. **detected at**: the entry's first frame with
  the person detected in the zone (``None``: never, the person was inside unseen).
* **corners** (of a box or polygon zone's floor, where the walk has the integrator crouch):
  the zone cells within ``CORNER_M`` of each that no camera sees, and the frames the person
  was *seen at* it. With ground truth: of the frames a person truly stood on the zone's floor
  within ``CORNER_M`` of the corner (``frames_near``), those in which the zone check found a
  seen (not lost) person in the zone or a detected foot point lay within ``CORNER_M`` of the
  corner; a corner visited but never seen is one where a crouching person cannot cause a STOP.
  Without: the frames with a detected foot point within ``CORNER_M`` of it (``frames_near``
  None).
* **feet hidden**: zone cells along the floor range of a box cut off at the bottom by a
  horizontal edge of the commissioning reference that no declared occluder explains
  (``monitor.commission.cut_feet``): "feet hidden here: declare an occluder".
* **gap**: frames between two detections of a person (from the first detection to the last)
  with nobody detected, longer than 1.5 frame intervals; it belongs to the zones the person
  was last seen in.
"""

from __future__ import annotations

import itertools
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from monitor.commission.cut_feet import undeclared_cuts
from monitor.commission.floor import ZoneFloor, feet_on_floor
from monitor.commission.truth import TruthFrame, aligned
from monitor.policy import SLOW, STOP
from monitor.zones import Cell
from monitor.zones.prepare import with_references

GAP_FACTOR = 1.5  # a gap is longer than this many frame intervals
CORNER_M = 0.5  # "at a corner": within this distance of it (two 0.25 m floor cells)


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
    faults: tuple[tuple[str, str], ...] = ()  # (source, fault) of the command's camera faults
    # floor points where a box was cut off by an undeclared fixture (``cut_feet``)
    cut_m: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class Entry:
    entry_s: float
    exit_s: float | None  # None: still inside at the end of the walk
    stop_s: float | None
    time_to_stop_s: float | None
    frames_inside: int
    detected_s: float | None = None  # first frame of the entry with a detection in the zone


@dataclass(frozen=True)
class Corner:
    corner_m: tuple[float, float]
    blind_cells: int  # zone cells within CORNER_M no camera sees
    frames_near: int | None  # ground truth: frames a person stood there (None: no truth)
    frames_seen: int  # frames a person was seen there

    @property
    def seen(self) -> bool:
        return self.frames_seen > 0


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
    corners: tuple[Corner, ...] = ()
    # cells where the walker's box was cut off by an undeclared fixture (``cut_feet``)
    feet_hidden: tuple[tuple[float, float], ...] = ()

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
    by_truth: bool = False  # entries counted from the ground truth too
    # {camera: {fault: frames}}: the frames whose command named a camera fault (frozen, lost,
    # blinded, moved, defocused): while one holds the walk proves nothing for that camera
    camera_faults: dict[str, dict[str, int]] = field(default_factory=dict)
    detected_frames: int = 0  # frames with a person detected (0: nobody was seen at all)

    def to_dict(self) -> dict:
        """JSON of the result (numbers rounded: the same walk gives the same text)."""
        return _rounded({
            "duration_s": self.duration_s, "frames": self.frames, "by_truth": self.by_truth,
            "frame_interval_s": self.frame_interval_s, "cell_m": self.cell_m,
            "zones": [{**asdict(z), "visible_fraction": z.visible_fraction,
                       "seen_fraction": z.seen_fraction,
                       "corners": [{**asdict(c), "seen": c.seen} for c in z.corners]}
                      for z in self.zones],
            "gaps": [asdict(g) for g in self.gaps],
            "camera_faults": self.camera_faults, "detected_frames": self.detected_frames,
            "seen_m": list(self.seen_m)})

    def zone(self, zone_id: str) -> ZoneWalk:
        return next(z for z in self.zones if z.zone_id == zone_id)


class WalkRecorder:
    """A driver sink (or replay ``publish`` callback) that keeps a ``StepSample`` per step."""

    def __init__(self, cell: Cell, references: Mapping[str, np.ndarray | None] | None = None,
                 band_px: tuple[float, float] = (0.0, 0.0)) -> None:
        self.cell = cell
        self.samples: list[StepSample] = []
        # each camera's commissioning reference: boxes cut off by an undeclared fixture
        self.prepared = with_references(cell.prepared, references) if references else None
        self.band_px = band_px

    def __call__(self, result) -> None:
        cmd = result.command
        named = tuple(sorted({r.zone_id for r in cmd.reasons if r.zone_id}))
        faults = tuple(sorted({(r.source or "?", r.fault) for r in cmd.reasons
                               if r.fault and r.fault.startswith("camera_")}))
        frame = result.frame
        if frame is None or result.persons is None:
            self.samples.append(StepSample(result.now, frame is not None, cmd.state, named,
                                           faults=faults))
            return
        report = result.zone_report
        hits = tuple(sorted({h.zone_id for h in report.hits if not h.lost})) \
            if report is not None else ()
        masked = set(report.masked) if report is not None else set()
        rows = [i for i in range(len(result.persons)) if i not in masked]
        boxes = result.persons.boxes_px[rows]
        feet = feet_on_floor(self.cell, frame.camera_id, boxes, frame.width, frame.height)
        cut = undeclared_cuts(self.prepared, frame.camera_id, boxes, self.band_px)
        self.samples.append(StepSample(
            result.now, True, cmd.state, named, hits, len(rows),
            tuple((float(x), float(y)) for x, y in feet), faults,
            tuple((float(x), float(y)) for x, y in cut)))


def analyse(samples: Sequence[StepSample], floors: Sequence[ZoneFloor],
            alarm_zones: Sequence[tuple[str, str]] = (),
            truth: Sequence[TruthFrame] | None = None, truth_name: str = "truth") -> WalkResult:
    """The walk's result. ``floors``: the volume zones' floor grids; ``alarm_zones``: (id,
    kind) of image-polygon protective/warning zones (entries only, no floor); ``truth``: the
    ground truth of each frame (a generated walk), which starts an entry at the first frame a
    person truly stands on a zone's floor (``InputError`` naming ``truth_name`` when it is
    another video's)."""
    frames = [s for s in samples if s.frame]
    times = [s.time_s for s in frames]
    interval = statistics.median(np.diff(times)) if len(times) >= 2 else 0.0
    if truth is not None:
        truth = aligned(truth, times, interval, truth_name)
    gaps = _gaps(frames, interval)
    seen = np.array([p for s in frames for p in s.feet_m], float).reshape(-1, 2)
    zones = []
    for f in floors:
        detected = [(bool(s.feet_m) and bool((f.cell_of(np.array(s.feet_m)) >= 0).any()))
                    or f.zone_id in s.hit_zones for s in frames]
        truly = [bool(t.floor_m) and bool((f.cell_of(np.array(t.floor_m)) >= 0).any())
                 for t in truth] if truth is not None else [False] * len(frames)
        zones.append(_zone(samples, frames, detected, truly, f.zone_id, f.kind, gaps, f,
                           truth))
    for zone_id, kind in alarm_zones:
        detected = [zone_id in s.hit_zones for s in frames]
        zones.append(_zone(samples, frames, detected, [False] * len(frames), zone_id, kind,
                           gaps, None))
    duration = (times[-1] - times[0] + interval) if times else 0.0
    return WalkResult(duration, len(frames), interval, floors[0].cell_m if floors else 0.0,
                      tuple(zones), gaps, tuple(map(tuple, seen.tolist())),
                      by_truth=truth is not None, camera_faults=camera_faults(frames),
                      detected_frames=sum(s.persons > 0 for s in frames))


def camera_faults(frames: Sequence[StepSample]) -> dict[str, dict[str, int]]:
    """{camera: {fault: frames whose command named it}}."""
    out: dict[str, dict[str, int]] = {}
    for s in frames:
        for source, fault in s.faults:
            counts = out.setdefault(source, {})
            counts[fault] = counts.get(fault, 0) + 1
    return {cam: dict(sorted(c.items())) for cam, c in sorted(out.items())}


def _zone(samples: Sequence[StepSample], frames: Sequence[StepSample], detected: list[bool],
          truly: list[bool], zone_id: str, kind: str, gaps: tuple[Gap, ...],
          floor: ZoneFloor | None, truth: Sequence[TruthFrame] | None = None) -> ZoneWalk:
    inside = [a or b for a, b in zip(detected, truly, strict=True)]
    entries = _entries(samples, frames, inside, detected, zone_id, kind)
    own_gaps = tuple(g for g in gaps if _gap_in(g, frames, inside))
    if floor is None:
        return ZoneWalk(zone_id, kind, 0, 0, 0, (), (), entries, own_gaps)
    seen = np.zeros(len(floor.centres_m), dtype=bool)
    for s in frames:
        k = floor.cell_of(np.array(s.feet_m)) if s.feet_m else np.zeros(0, int)
        seen[k[k >= 0]] = True
    blind = floor.centres_m[~floor.visible]
    unvisited = floor.centres_m[floor.visible & ~seen]
    corners = tuple(_corner(c, floor, frames, truth) for c in floor.corners_m)
    return ZoneWalk(zone_id, kind, len(floor.centres_m), int(floor.visible.sum()),
                    int(seen.sum()), _points(blind), _points(unvisited), entries, own_gaps,
                    corners, _points(floor.centres_m[_cells_hit(floor, frames, "cut_m")]))


def _cells_hit(floor: ZoneFloor, frames: Sequence[StepSample], attr: str) -> np.ndarray:
    """(K,) bool: the zone's cells with a point of the frames' ``attr`` on them."""
    hit = np.zeros(len(floor.centres_m), dtype=bool)
    for s in frames:
        points = getattr(s, attr)
        if points:
            k = floor.cell_of(np.array(points))
            hit[k[k >= 0]] = True
    return hit


def _corner(corner: np.ndarray, floor: ZoneFloor, frames: Sequence[StepSample],
            truth: Sequence[TruthFrame] | None) -> Corner:
    near_cells = np.hypot(*(floor.centres_m - corner).T) <= CORNER_M
    blind = int((near_cells & ~floor.visible).sum())

    def close(points) -> bool:
        p = np.array(points, float).reshape(-1, 2)
        return bool(len(p)) and bool((np.hypot(*(p - corner).T) <= CORNER_M).any())

    def on_floor_close(points) -> bool:
        p = np.array(points, float).reshape(-1, 2)
        p = p[floor.cell_of(p) >= 0]
        return close(p)

    if truth is None:
        seen = sum(close(s.feet_m) for s in frames)
        return Corner(_points(corner[None])[0], blind, None, seen)
    near = [on_floor_close(t.floor_m) for t in truth]
    seen = sum(n and (floor.zone_id in s.hit_zones or close(s.feet_m))
               for n, s in zip(near, frames, strict=True))
    return Corner(_points(corner[None])[0], blind, sum(near), seen)


def _entries(samples: Sequence[StepSample], frames: Sequence[StepSample], inside: list[bool],
             detected: list[bool], zone_id: str, kind: str) -> tuple[Entry, ...]:
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
        seen = next((frames[i].time_s for i in range(start, k) if detected[i]), None)
        out.append(Entry(t_in, t_out, stop, None if stop is None else stop - t_in, k - start,
                         seen))
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
