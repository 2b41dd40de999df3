"""Tracked persons and object permanence: a person lost near a zone keeps that zone occupied.

Detectors miss people: behind the robot base for a frame, merged into a neighbour's box, hidden
by a part carried past the camera, between two frames at 1 fps. A per-frame zone answer would
then read "clear" exactly when a reset or a RUN is most dangerous. So persons are tracked
across frames (ByteTrack from ``supervision``: association by box overlap with a Kalman motion
model) for their names, and every track that is lost leaves an *area* where the person could be
(``monitor.tracking.whereabouts``): it grows at walking speed through whatever the camera does not
see free and shrinks where a working camera sees it free for ``clear_time``. While the area touches
a protective or warning zone it is a *hold*: every frame, the camera's zone report carries
``ZoneHit(..., track_id=k, lost=True, lost_since=t)`` for each zone it touches, until

* the area no longer touches the zone (the camera has seen it free), or
* an operator confirms the cell clear (``ResetRequest(confirm_clear=True)``; see
  ``PersonTracker.drop_holds``).

Ids are names only: a person re-found, or a new person near where a lost one was, never ends a
hold. A track lost at an image edge moving outwards is marked ``left_view`` so that the cell's
other monitors can take it over (``monitor.tracking.handover``).

Everything here is deterministic: no wall clock, the frame's capture time is passed in.
"""

from __future__ import annotations

import math
import statistics
import warnings
from dataclasses import replace

import numpy as np

from monitor.tracking import exits, pairs, pockets
from monitor.tracking.gaps import GapWatch
from monitor.tracking.pairs import PairWatch, Split
from monitor.tracking.pockets import PocketBook
from monitor.tracking.track_record import TALL_WINDOW_S, TrackRecord
from monitor.tracking.track_types import (
    HiddenCells,
    Hold,
    ToFloor,
    Track,
    TrackerConfig,
    TrackUpdate,
    lost_person_index,
)
from monitor.tracking.whereabouts import (
    HOLD_KINDS,
    FreeElsewhere,
    HeldZone,
    Whereabouts,
    ZonesOf,
    grow,
    union_zones,
)
from monitor.types import Persons, ZoneHit, ZoneReport


def _supervision():
    """The ``supervision`` package, imported when the first tracker is made, not with this
    module: it pulls in scipy's interpolation and its annotators (over a second on a small
    host), and the CLI's zone commands read this module's settings without tracking anyone."""
    with warnings.catch_warnings():  # ByteTrack announces its move to the `trackers` package
        warnings.simplefilter("ignore", FutureWarning)
        import supervision

    return supervision


def _bottom_centre(boxes: np.ndarray) -> np.ndarray:
    return np.stack([(boxes[:, 0] + boxes[:, 2]) * 0.5, boxes[:, 3]], axis=1)


class PersonTracker:
    """Persistent person ids for one camera, and where its lost persons could be (their
    areas, ``monitor.tracking.whereabouts``; an area touching a zone is a hold).

    ``to_floor`` (a camera calibration's ``pixel_to_floor``) adds floor positions and
    velocities to the tracks; without it tracks are image-only.
    """

    def __init__(self, config: TrackerConfig | None = None, to_floor: ToFloor | None = None
                 ) -> None:
        self.config = config or TrackerConfig()
        self.to_floor = to_floor
        sv = self._sv = _supervision()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            # activation threshold 0: every detection the detector reports gets a track
            self._byte = sv.ByteTrack(track_activation_threshold=0.0,
                                      lost_track_buffer=30,
                                      minimum_matching_threshold=self.config.matching_threshold,
                                      frame_rate=30, minimum_consecutive_frames=1)
        self._byte.max_time_lost = self._buffer_frames(30.0)
        self._records: dict[int, TrackRecord] = {}
        self._by_byte_id: dict[int, int] = {}  # ByteTrack's id -> our track id
        self._next_id = 1
        self._last_time: float | None = None
        self._intervals: list[float] = []  # the last frame intervals (s), for the frame rate
        self._reidentified: list[tuple[int, int]] = []
        self._guessed: set[int] = set()  # rows given a lost track's id by nearness, not ByteTrack
        self._byte_ids: dict[int, int] = {}  # row -> ByteTrack's id in the newest frame
        self.where = Whereabouts(self.config.areas())
        self.pockets = PocketBook()  # enclosed hidden regions with a count (``pockets``)
        # persons seen again where their hold ended (``gaps``)
        self.gaps = GapWatch(self.config.walk_speed_mps, self.config.height_m,
                             self.config.edge_margin_px)
        # lost track -> the seen track whose box swallowed it: the person hidden right behind
        # that box walks with it (``_follow_carriers``)
        self._carriers: dict[int, int] = {}
        self.pairs = PairWatch()  # tracks whose box is known to hold two persons (``pairs``)
        self._splits: list[Split] = []  # areas of persons who stepped out of such a box
        self._boxes_before: dict[int, np.ndarray] = {}  # track -> box in the previous frame

    def _split_from(self, track_id: int, box: np.ndarray, seen: float, height_px: float
                    ) -> None:
        """A box that held two persons holds one now (``monitor.tracking.pairs``: two heads
        before, one now; or wide from its first sighting, narrow now): the tracker keeps its
        id on one of them, and the other, never seen alone, has no track to lose. They get an
        area of their own from where the box held both, under a new person number no
        ByteTrack track links to (the name link never ends it: only seen free, the bounded
        life, a pocket's count or a confirm-clear do). Without it one of a pair boxed as one
        stepped behind the cabinet and a plain reset was accepted with them inside
        (tests/test_name_link_attacks.py)."""
        split_id = self._next_id
        self._next_id += 1
        # behind fixtures only: in a busy cell an area that grows behind every passer-by
        # lived its whole bounded life for a detector's miss of one of two persons
        self.where.lose(split_id, box, seen, height_px=height_px, behind_persons=False)
        self._splits.append(Split(split_id, track_id, np.asarray(box, np.float64).copy(),
                                  seen))

    def _pairs_again(self, rows_to_id: list[int], boxes: np.ndarray, new_rows: set[int],
                     now: float, frame_size: tuple[int, int]) -> None:
        """A split's area ends when the pair is seen as two again within ``lost_track_s``:
        the track that kept the box seen by its own association (not a guess) and a new box
        (a row no track of the previous frame was associated with) within a walk of where
        the pair stood that can only have come from floor the camera shows
        (``pairs.out_in_view``). A detector that missed one of two persons side by side for a
        frame then leaves no area riding on passers-by; one who stepped behind a fixture
        (or is hidden behind someone) is not seen coming back this way."""
        grid, hidden, cfg = self.where.grid, self.where.hidden, self.config
        kept = []
        for split in self._splits:
            if split.area_id not in self.where.areas \
                    or now - split.since > cfg.lost_track_s + 1e-9:
                continue
            kept.append(split)
            if split.track_id not in rows_to_id or grid is None or hidden is None \
                    or rows_to_id.index(split.track_id) in self._guessed:
                continue
            before = [b for t, b in self._boxes_before.items() if t != split.track_id]
            others = grid.cells_under(np.array(before).reshape(-1, 4), cfg.below)
            height = max(float(split.box[3] - split.box[1]), 1.0)
            px_per_s = cfg.walk_speed_mps / cfg.height_m * height * cfg.reach_margin
            since = grow(grid.cells_under(split.box, cfg.below),
                         math.ceil(px_per_s * (now - split.since) / grid.cell_px))
            dt = now - (self.where.last_time if self.where.last_time is not None else now)
            for row in new_rows:
                if (grid.cells_under(boxes[row], 0.0) & since).any() and pairs.out_in_view(
                        grid, hidden, boxes[row], others,
                        math.ceil(px_per_s * max(dt, 0.0) / grid.cell_px), frame_size,
                        cfg.edge_margin_px):
                    self.where.found(split.area_id, clear_view=True)
                    kept.pop()
                    break
        self._splits = kept

    def _buffer_frames(self, fps: float) -> int:
        return max(1, math.ceil(self.config.lost_track_s * fps))

    def _measure_rate(self, now: float) -> None:
        """ByteTrack counts frames: keep its lost-track buffer at ``lost_track_s`` of the
        measured frame rate (median of the last intervals)."""
        if self._last_time is not None and now > self._last_time:
            self._intervals = [*self._intervals[-9:], now - self._last_time]
            # statistics.median: the same value as np.median, 10x cheaper on ten floats
            fps = 1.0 / statistics.median(self._intervals)
            self._byte.max_time_lost = self._buffer_frames(fps)
        self._last_time = now

    def label(self, track_id: int) -> str:
        """``person 6`` or ``person 6 (was person 1?)``."""
        rec = self._records.get(track_id)
        return rec.label() if rec is not None else f"person {track_id}"

    # ---------------------------------------------------------------------------------------
    @property
    def tracks(self) -> tuple[Track, ...]:
        return tuple(r.snapshot(self._held(r.track_id) if r.lost else ())
                     for r in sorted(self._records.values(), key=lambda r: r.track_id))

    def _held(self, track_id: int) -> tuple[HeldZone, ...]:
        area = self.where.areas.get(track_id)
        return area.zones if area is not None else ()

    @property
    def holds(self) -> tuple[Hold, ...]:
        """Every lost person whose area touches a protective or warning zone."""
        out = []
        for tid, area in sorted(self.where.areas.items()):
            if area.zones:
                rec = self._records.get(tid)
                out.append(Hold(tid, area.zones, area.lost_since, area.box_px,
                                rec.seen_as if rec is not None else None))
        return tuple(out)

    def held_hits(self) -> tuple[ZoneHit, ...]:
        """One ``lost=True`` hit per held zone of every lost person."""
        return tuple(ZoneHit(z.zone_id, z.kind, lost_person_index(h.track_id), z.speed_scale,
                             None, h.track_id, True, h.lost_since)
                     for h in self.holds for z in h.zones)

    def drop_holds(self) -> tuple[Hold, ...]:
        """An operator confirmed the cell clear: every lost person's area ends (seen persons
        are untouched: one walking into a pocket is counted in once lost) and every pocket is
        counted empty. Returns the holds dropped."""
        dropped = self.holds
        self.where.drop()
        self.where.take_ended()  # said by the confirm-clear alert
        if self.where.last_time is not None:
            pockets.confirm(self.pockets, self.where.last_time)
        return dropped

    def blind(self) -> None:
        """A frame this camera could not judge (a detector error): nothing was seen free, so
        every seen-free streak starts again; nobody knows who went into a pocket or came out."""
        self.where.blind()
        if self._last_time is not None:
            pockets.unknown(self.pockets, "a frame the camera could not judge", self._last_time)

    # ---------------------------------------------------------------------------------------
    def update(self, persons: Persons, report: ZoneReport | None, now: float,
               frame_size: tuple[int, int], zones_of: ZonesOf | None = None, *,
               working: bool = True, hidden: HiddenCells | None = None,
               hidden_key: object = None, clear_time: float = 1.0,
               zones_key: object = None, free_elsewhere: FreeElsewhere | None = None,
               feet_bottom_px: np.ndarray | None = None,
               heads: np.ndarray | None = None) -> TrackUpdate:
        """Associate this frame's persons with the tracks; return their ids and the report
        with track ids on the seen hits plus one lost hit per held zone.

        ``report`` is the zone answer for ``persons`` (None: unknown). ``now`` is the frame's
        capture time; ``frame_size`` its (width, height). Every track lost in this frame
        leaves an area where the person could be; ``zones_of`` (the zone check for other
        boxes; None: no zones) says which zones an area touches (its answers kept while
        ``zones_key`` is the same; None: this frame only). ``working`` False: the camera's
        view cannot be trusted in this frame (a STOP fault of the camera or detector), nothing
        is seen free. ``hidden(grid)``: the cells no person could be seen in (recomputed
        when ``hidden_key`` changes). A cell is free once seen free for ``clear_time``, by
        this camera or (``free_elsewhere``, floor points; needs ``to_floor``) another one.
        ``feet_bottom_px`` (per row; NaN: feet in view): how far below a cut-off box its
        hidden feet may be (``Whereabouts.update``). ``heads`` (per row; ``pairs.heads_in_boxes``,
        None: not counted): the heads seen in each box, two persons in one box when two.
        """
        boxes = np.asarray(persons.boxes_px, np.float64).reshape(-1, 4)
        n = len(boxes)
        self._measure_rate(now)
        self._reidentified = []
        self.where.view(int(frame_size[0]), int(frame_size[1]), hidden, hidden_key)
        before = {h.track_id: h for h in self.holds}
        rows_to_id = self._associate(boxes, np.asarray(persons.scores, np.float64), now)
        # pockets (monitor.tracking.pockets): a frame the camera cannot judge loses every
        # count; persons appearing now, not seen in the previous frame, may come out of one
        if not working:
            pockets.unknown(self.pockets, "a frame the camera could not judge", now)
        appearing = [row for row, tid in enumerate(rows_to_id)
                     if tid not in self._records or self._records[tid].lost]
        pockets.count_exits(self.pockets, self.where, boxes, appearing, now)
        self.gaps.appeared(boxes, appearing, rows_to_id, now, statistics.median(
            self._intervals) if self._intervals else 0.0, frame_size)
        # a person appearing where only one lost person could have been is them, whatever
        # id the box gets (monitor.tracking.exits): their area ends
        for tid in exits.came_out(self.where, boxes, appearing, now, self.pockets.single):
            self.where.came_out(tid)
        pockets.seen(self.pockets, self.where, rows_to_id, boxes)
        row_zones = self._row_zones(report, n)
        floors: list[np.ndarray | None] = [None] * n
        if self.to_floor is not None and n:
            xy, located = self.to_floor(_bottom_centre(boxes))
            floors = [np.asarray(xy[i], np.float64) if located[i] else None for i in range(n)]

        cut_rows = np.full(n, np.nan) if feet_bottom_px is None \
            else np.asarray(feet_bottom_px, np.float64).reshape(-1)
        seen_now = set(rows_to_id)
        head_rows = np.full(n, pairs.UNKNOWN) if heads is None \
            else np.asarray(heads, np.int64).reshape(-1)
        moved: dict[int, tuple[np.ndarray, float, bool]] = {}  # row -> old box, time, left
        for row, tid in enumerate(rows_to_id):
            rec = self._records.get(tid)
            if rec is None:
                rec = self._records[tid] = TrackRecord(tid, boxes[row].copy(), now)
                rec.byte_id = self._byte_ids.get(row, -1)
                rec.zones = row_zones[row] if row_zones is not None else ()
                self._place(rec, boxes[row], floors[row], now, first=True)
                rec.feet_bottom = float(cut_rows[row])
                self.pairs.seen(tid, boxes[row], int(head_rows[row]))
                for new, old in self._reidentified:
                    if new == tid and old in self._records:
                        rec.was = old
                        self._records[old].seen_as = tid
                continue
            # seen again by the tracker's own association: its area ends while all of it is
            # in view (a flicker), or when the person is seen in clear view (the name link:
            # the same person came out from behind the fixture)
            # (only within the tracker's own buffer, ``lost_track_s``, and only when the
            # track has not been given to a box by a guess since the loss: after longer
            # behind a fixture, a person stepping out there may as well be someone else)
            if row not in self._guessed and self._same_person(rec, row, boxes, now):
                # swallowed by a neighbour's box and now seen apart from it: both seen
                carrier = self._carriers.get(tid)
                apart = rec.lost and carrier is not None and carrier != tid \
                    and carrier in seen_now
                self.where.found(tid, self._clear_view(rec, row, boxes, now, frame_size),
                                 apart=apart)
            old_box, old_seen = rec.box.copy(), rec.last_seen
            stepped = self.pairs.seen(tid, boxes[row], int(head_rows[row]))
            # only a track seen in the previous frame: one re-found after a loss left its
            # own area there (a split then kept ghost holds in the street scene, measured)
            if stepped is not None and old_seen == self.where.last_time \
                    and not pairs.seen_beside(stepped, row, boxes):
                self._split_from(tid, stepped, old_seen, rec.tall_px())
            self._place(rec, boxes[row], floors[row], now, first=False)
            rec.byte_id = self._byte_ids.get(row, -1)
            if row_zones is not None:
                left = {z.zone_id for z in rec.zones} - {z.zone_id for z in row_zones[row]}
                moved[row] = (old_box, old_seen, bool(left))
                rec.zones = row_zones[row]
            rec.lost, rec.seen_as, rec.left_view = False, None, False
            rec.feet_bottom = float(cut_rows[row])

        for rec in self._records.values():
            if rec.track_id in seen_now or rec.lost:
                continue
            rec.lost = True
            rec.left_view = self._leaving_view(rec, frame_size)
            pockets.lost(self.pockets, rec.track_id)
            into = self._merged_into(rec.box, boxes)
            # swallowed by a neighbour's box: hidden right behind (or in front of) them
            self.where.lose(rec.track_id, rec.box, rec.last_seen, behind=bool(into),
                            height_px=rec.tall_px(), feet_bottom_px=rec.feet_bottom)
            for row in into:  # whichever identity the merged box keeps: where it stood too
                pockets.swallowed(self.pockets, rec.track_id, rows_to_id[row])
                self._carriers.setdefault(rec.track_id, rows_to_id[row])
                old_box, old_seen, left = moved.get(row, (None, 0.0, False))
                if left and old_box is not None:
                    self.where.lose(rows_to_id[row], old_box, old_seen, behind=True)
        self._follow_carriers(rows_to_id, boxes, now)
        self._pairs_again(rows_to_id, boxes, {*appearing, *self._guessed}, now, frame_size)
        self._boxes_before = {tid: boxes[row].copy() for row, tid in enumerate(rows_to_id)}
        self.where.update(now, boxes, working, clear_time, zones_of, zones_key,
                          free_elsewhere, self.to_floor, feet_bottom_px,
                          settle=lambda w: pockets.settle(self.pockets, w, now))

        for tid in [t for t, r in self._records.items() if r.lost and t not in self.where.areas
                    and now - r.last_seen > self.config.forget_after_s]:
            del self._records[tid]
            self.pairs.forget(tid)

        after = {h.track_id: h for h in self.holds}
        started = tuple(h for t, h in after.items() if t not in before)
        ended = tuple(h for t, h in before.items() if t not in after)
        out = None
        if report is not None:
            seen_hits = tuple(replace(h, track_id=rows_to_id[h.person])
                              if 0 <= h.person < n else h for h in report.hits)
            out = replace(report, hits=seen_hits + self.held_hits())
        ended_areas = self.where.take_ended()
        self.gaps.ended(ended_areas, now, boxes)
        rules = tuple((a.track_id, rule) for a, rule in ended_areas)
        return TrackUpdate(tuple(rows_to_id), out, started, ended, tuple(self._reidentified),
                           rules)

    # ---------------------------------------------------------------------------------------
    def _associate(self, boxes: np.ndarray, scores: np.ndarray, now: float) -> list[int]:
        """Our track id for every row: ByteTrack's association first; rows it leaves without
        an id (a new person's first frames) or gives a new id re-find a track that is not
        seen in this frame near where it was last seen, or start a new one. "Near": within
        ``near_factor`` box widths, or (a track holding no zone) as far as a person walks in
        the time since it was seen; a new person that far from a track holding a zone gets a
        new id, noted as perhaps that person (``reidentified``), and the hold stays."""
        n = len(boxes)
        self._guessed = set()
        byte_ids = np.full(n, -1, np.int64)
        self._byte_ids: dict[int, int] = {}
        if n:
            dets = self._sv.Detections(xyxy=boxes.astype(np.float32), confidence=scores.astype(
                np.float32), data={"row": np.arange(n)})
            tracked = self._byte.update_with_detections(dets)
            if len(tracked):
                byte_ids[np.asarray(tracked.data["row"], int)] = tracked.tracker_id
        else:
            self._byte.update_with_detections(self._sv.Detections.empty())

        ids: list[int | None] = [None] * n
        for row in range(n):
            tid = self._by_byte_id.get(int(byte_ids[row]))
            if tid is not None and tid not in ids:
                ids[row] = tid
        free = [r for r in self._records.values() if r.track_id not in ids]
        rows = [row for row in range(n) if ids[row] is None]
        if rows and free:
            # nearest pairs first, each row and each track used once
            bc_rows = _bottom_centre(boxes[rows])
            bc_free = _bottom_centre(np.stack([r.box for r in free]))
            dist = np.linalg.norm(bc_rows[:, None, :] - bc_free[None, :, :], axis=2)
            width = np.maximum((boxes[rows, 2] - boxes[rows, 0])[:, None],
                               np.array([r.box[2] - r.box[0] for r in free])[None, :])
            near = dist <= self.config.near_factor * np.maximum(width, 1.0)
            reach = dist <= self._walk_reach(boxes[rows], free, now)
            holding = np.array([bool(self._held(r.track_id)) for r in free])[None, :]
            guess = reach & ~near & holding  # never ends a hold: said, not merged
            near |= reach & ~holding
            for flat in np.argsort(dist, axis=None, kind="stable"):
                i, j = divmod(int(flat), len(free))
                if near[i, j] and ids[rows[i]] is None and free[j].track_id not in ids:
                    ids[rows[i]] = free[j].track_id
                    self._guessed.add(rows[i])
            guesses = [(i, j) for i, j in zip(*np.nonzero(guess), strict=True)]
        else:
            guesses = []
        claimed: set[int] = set()
        for row in range(n):
            if ids[row] is None:
                ids[row] = self._next_id
                self._next_id += 1
                # the nearest lost holder within walking reach: perhaps this person
                for i, j in sorted(guesses, key=lambda g: float(dist[g])):
                    if rows[i] == row and free[j].track_id not in claimed:
                        claimed.add(free[j].track_id)
                        self._reidentified.append((ids[row], free[j].track_id))
                        break
            if byte_ids[row] >= 0:
                self._by_byte_id[int(byte_ids[row])] = ids[row]
                self._byte_ids[row] = int(byte_ids[row])
        return [int(t) for t in ids]

    def _row_zones(self, report: ZoneReport | None, n: int
                   ) -> list[tuple[HeldZone, ...]] | None:
        if report is None:
            return None
        per_row: list[list[HeldZone]] = [[] for _ in range(n)]
        for h in report.hits:
            if 0 <= h.person < n and not h.lost and h.kind in HOLD_KINDS:
                per_row[h.person].append(HeldZone(h.zone_id, h.kind, float(h.speed_scale)))
        return [union_zones(z) for z in per_row]

    def _place(self, rec: TrackRecord, box: np.ndarray, floor: np.ndarray | None, now: float,
               first: bool) -> None:
        """Move a record to its new box; update image and floor velocities."""
        a = self.config.velocity_smoothing
        dt = now - rec.last_seen
        if not first and dt > 0:
            old_c = (rec.box[:2] + rec.box[2:]) * 0.5
            new_c = (box[:2] + box[2:]) * 0.5
            rec.velocity = a * (new_c - old_c) / dt + (1 - a) * rec.velocity
        if floor is not None and rec.floor is not None and not first and dt > 0:
            sample = (floor - rec.floor) / dt
            rec.floor_velocity = sample if rec.floor_velocity is None else \
                a * sample + (1 - a) * rec.floor_velocity
        elif floor is None:
            rec.floor_velocity = None
        rec.floor = floor
        rec.box = box.copy()
        rec.last_seen = now
        rec.heights = [(t, h) for t, h in rec.heights if now - t <= TALL_WINDOW_S]
        rec.heights.append((now, float(box[3] - box[1])))

    def _follow_carriers(self, rows_to_id: list[int], boxes: np.ndarray, now: float) -> None:
        """A track lost into a neighbour's box may be hidden right behind them and walk with
        them: while that box is seen, the lost track's area takes the cells of that box
        where their feet may be, at their own depth within a walk since the loss
        (``Whereabouts.carry``; the place it was swallowed is kept as well). Else a person
        boxed with a colleague who steps behind a fixture while still boxed as one leaves no
        area at the fixture, and the cell runs with them there once the colleague has left.
        Only within the area's bounded life (nobody walks hidden behind others for ever,
        docs/tracking.md); ends when the track is seen again, its area ends, or the carrier
        is not seen."""
        cfg = self.config
        for tid, carrier in list(self._carriers.items()):
            rec, area = self._records.get(tid), self.where.areas.get(tid)
            if rec is None or not rec.lost or area is None or carrier not in rows_to_id \
                    or now - rec.last_seen >= self.where.life_s(area) - 1e-9:
                del self._carriers[tid]
                continue
            reach_px = cfg.walk_speed_mps / cfg.height_m * area.box_height_px \
                * cfg.reach_margin * (now - rec.last_seen)
            self.where.carry(tid, rec.box, boxes[rows_to_id.index(carrier)], reach_px)

    def _merged_into(self, box: np.ndarray, boxes: np.ndarray) -> list[int]:
        """Rows of this frame's boxes that cover ``merge_ios`` or more of a lost box."""
        if not len(boxes):
            return []
        area = max((box[2] - box[0]) * (box[3] - box[1]), 1e-9)
        w = np.minimum(box[2], boxes[:, 2]) - np.maximum(box[0], boxes[:, 0])
        h = np.minimum(box[3], boxes[:, 3]) - np.maximum(box[1], boxes[:, 1])
        cover = np.clip(w, 0, None) * np.clip(h, 0, None) / area
        return np.flatnonzero(cover >= self.config.merge_ios).tolist()

    def _same_person(self, rec: TrackRecord, row: int, boxes: np.ndarray, now: float) -> bool:
        """The row is the lost track's own person again, as far as a tracker can say: the
        same ByteTrack track as at the last sighting (not only an id that ByteTrack's track
        was once mapped to: in a busy scene a merged box's ByteTrack track passes on to a
        passer-by while the id went with the person), standing within a walk of the loss's
        area since the loss."""
        area = self.where.areas.get(rec.track_id)
        grid = self.where.grid
        if area is None or grid is None or rec.byte_id < 0 \
                or self._byte_ids.get(row, -2) != rec.byte_id:
            return False
        cfg = self.config
        reach_px = cfg.walk_speed_mps / cfg.height_m * area.box_height_px * cfg.reach_margin \
            * max(0.0, now - area.lost_since)
        steps = math.ceil(min(reach_px / grid.cell_px, grid.nx + grid.ny))
        return bool((grid.cells_under(boxes[row], 0.0) & grow(area.cells, steps)).any())

    def _clear_view(self, rec: TrackRecord, row: int, boxes: np.ndarray, now: float,
                    frame_size: tuple[int, int]) -> bool:
        """Seen again in clear view soon enough to be the name link: within ByteTrack's
        buffer (``lost_track_s``; after longer behind a fixture a person stepping out there
        may as well be someone else) and never after a sighting since the loss, the whole
        box inside the image (off its borders), its feet on cells the camera sees (none
        hidden) and no other box of the frame over it."""
        area = self.where.areas.get(rec.track_id)
        if area is None or abs(area.lost_since - rec.last_seen) > 1e-9 \
                or now - rec.last_seen > self.config.lost_track_s + 1e-9:
            return False
        w, h = frame_size
        m = self.config.edge_margin_px
        box = boxes[row]
        x1, y1, x2, y2 = (float(v) for v in box)
        if not (x1 > m and y1 > m and x2 < w - m and y2 < h - m):
            return False
        grid, hidden = self.where.grid, self.where.hidden
        if grid is None or hidden is None or (grid.cells_under(box, 0.0) & hidden).any():
            return False
        return not self._merged_into(box, np.delete(boxes, row, axis=0))

    def _leaving_view(self, rec: TrackRecord, frame_size: tuple[int, int]) -> bool:
        """Box at the left, right or bottom image border and moving outwards across it. Not
        the top: a head cut off there says nothing of the feet, which are still in view."""
        w, h = frame_size
        m, v = self.config.edge_margin_px, self.config.exit_speed_pxps
        x1, _, x2, y2 = rec.box
        vx, vy = rec.velocity
        return bool((x1 <= m and vx <= -v) or (x2 >= w - m and vx >= v)
                    or (y2 >= h - m and vy >= v))

    def _walk_reach(self, rows: np.ndarray, free: list[TrackRecord], now: float) -> np.ndarray:
        """(rows, free) pixels a person can walk since each free track was last seen, at
        ``walk_speed_mps``, scaled by the box height (a ``height_m`` person; the larger of the
        two boxes), for at most ``reach_max_s``."""
        cfg = self.config
        dt = np.clip(np.array([now - r.last_seen for r in free]), 0.0, cfg.reach_max_s)
        heights = np.maximum((rows[:, 3] - rows[:, 1])[:, None],
                             np.array([r.box[3] - r.box[1] for r in free])[None, :])
        return cfg.walk_speed_mps / cfg.height_m * heights * dt[None, :]


# the tracker's types (monitor.tracking.track_types), where its callers have always found them
__all__ = ["HiddenCells", "Hold", "PersonTracker", "ToFloor", "Track", "TrackUpdate",
           "TrackerConfig", "lost_person_index"]
