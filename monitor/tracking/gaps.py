"""A detector missing a person for longer than ``clear_time``, seen at run time.

A lost person's area gives up floor the camera has shown empty for the policy's
``clear_time``: a detector that misses a person standing in open view for that long ends the
hold while they are still there (the walk test measures this once, at commissioning:
``monitor.commission.verdict.detector_gaps``). Light, a dirty lens or a model at the edge of
its envelope change that later, so the tracker watches for it on every frame: an area ended
by "seen free" with nobody of their size in view near it, whose person then appears again
within a walk of where they were lost, soon (within ``walk_gap_s``: a box of their size, whole
in the picture, the only such box and the only such loss), means the camera showed the floor
empty while they were there. The watch cannot tell the same person from another one stepping
out there, so it only reports (an alert naming the clear_time that would have held them); it
never holds or releases anything.

Pure bookkeeping over boxes and times; ``PersonTracker`` feeds it (``monitor.tracking.tracks``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from monitor.tracking.whereabouts import LostArea

SEEN_FREE = "seen free"  # the one ending rule that says the camera showed the floor empty


@dataclass(frozen=True)
class DetectorGap:
    """A person seen again where their hold had ended as seen free."""

    track_id: int  # the lost person's id
    seen_as: int  # the id of the box seen again on their spot (may be the same)
    lost_at: float  # capture time of the last frame they were seen in
    seen_again: float  # capture time of the frame they are seen in again
    missed_frames: int  # frames in between (at the measured frame interval)
    interval_s: float  # the measured frame interval (0: not known yet)
    box_px: tuple[float, float, float, float]  # the box seen again

    @property
    def clear_time_s(self) -> float:
        """A clear_time above this holds the person through the gap with a frame to spare:
        the missed frames' floor is seen empty for one interval less (the walk test's figure,
        ``monitor.commission.verdict``)."""
        if self.interval_s <= 0 or self.missed_frames <= 0:
            return self.seen_again - self.lost_at
        return self.missed_frames * self.interval_s


@dataclass
class _Ended:
    track_id: int
    lost_at: float
    ended_at: float
    box: np.ndarray


@dataclass
class GapWatch:
    """The areas ended as seen free in the last ``window_s`` seconds, and the gaps found."""

    # the tracker's walk (``TrackerConfig.walk_speed_mps``, ``height_m``) and image border
    # margin (``edge_margin_px``: a box this close to it may be someone coming in)
    walk_speed_mps: float
    height_m: float
    edge_px: float
    window_s: float = 3.0  # how long after an area ended a sighting near it counts
    same_size: float = 1.3  # the new box's height within this factor of the last one's
    # seen again within this long after the loss (later, in a busy scene someone else has
    # walked up: measured, the synthetic detector's boxes of two passers-by on one spot agree)
    walk_gap_s: float = 2.5
    _ended: list[_Ended] = field(default_factory=list)
    _found: list[DetectorGap] = field(default_factory=list)

    def ended(self, areas: list[tuple[LostArea, str]], now: float,
              boxes_px: np.ndarray) -> None:
        """Areas that ended in this frame, each with its rule: the seen-free ones with no box
        of this frame (``boxes_px``) within a walk of them are kept (a person seen under
        another id was not missed)."""
        boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
        for area, rule in areas:
            if rule != SEEN_FREE or area.behind or area.merged:
                continue
            ended = _Ended(area.track_id, area.lost_since, now,
                           np.asarray(area.box_px, np.float64))
            if not any(self._within_walk(ended, box, now) for box in boxes):
                self._ended.append(ended)

    def appeared(self, boxes_px: np.ndarray, rows: list[int], ids: list[int], now: float,
                 interval_s: float, frame_size: tuple[int, int]) -> None:
        """Persons appearing in this frame (``rows`` of ``boxes_px``, with their ids): the
        one box near a recently ended area, and near no other, is a gap (areas ended more
        than ``window_s`` ago are forgotten here, once a frame)."""
        boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
        self._ended = [e for e in self._ended if now - e.ended_at <= self.window_s]
        w, h = frame_size
        m = self.edge_px
        whole = [r for r in rows if boxes[r, 0] > m and boxes[r, 1] > m
                 and boxes[r, 2] < w - m and boxes[r, 3] < h - m]
        near = {id(e): [r for r in whole if self._within_walk(e, boxes[r], now)]
                for e in self._ended}
        for hit in list(self._ended):
            if len(near[id(hit)]) != 1:
                continue
            row = near[id(hit)][0]
            if sum(row in rs for rs in near.values()) != 1:
                continue  # near two losses: whose it is cannot be said
            box = boxes[row]
            self._ended.remove(hit)
            frames = max(0, round((now - hit.lost_at) / interval_s) - 1) \
                if interval_s > 0 else 0
            self._found.append(DetectorGap(hit.track_id, int(ids[row]), hit.lost_at, now,
                                           frames, float(interval_s),
                                           tuple(float(v) for v in box)))  # type: ignore[arg-type]

    def _within_walk(self, ended: _Ended, box: np.ndarray, now: float) -> bool:
        """``box`` is of the lost person's size and (within ``walk_gap_s`` of the loss) its
        feet within a walk (at ``walk_speed_mps`` since the last sighting, plus half a box
        width) of theirs."""
        h0, h1 = ended.box[3] - ended.box[1], box[3] - box[1]
        if not (h0 > 0 and h1 > 0 and h0 / self.same_size <= h1 <= h0 * self.same_size):
            return False
        if now - ended.lost_at > self.walk_gap_s:
            return False
        reach = self.walk_speed_mps / self.height_m * max(h0, h1) * (now - ended.lost_at) \
            + 0.5 * max(ended.box[2] - ended.box[0], box[2] - box[0])
        feet0 = np.array([(ended.box[0] + ended.box[2]) * 0.5, ended.box[3]])
        feet1 = np.array([(box[0] + box[2]) * 0.5, box[3]])
        return bool(np.linalg.norm(feet1 - feet0) <= reach)

    def take(self) -> list[DetectorGap]:
        """The gaps found since the last call."""
        out, self._found = self._found, []
        return out
