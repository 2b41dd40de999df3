"""Where a lost person could be: kept until a working camera has seen it free.

The rule 3-D safety systems use: **space no working camera sees is occupied; space a working
camera sees empty is free.** A person the tracker loses (behind a fixture, merged with a
neighbour, missed by a flickering detector, between two frames at 1 fps) is not gone: from the
moment of the loss the monitor keeps the *area* of the image they could be standing in,

* starting from their last box (the feet may be anywhere under it, or just below it when
  hidden),
* growing every frame by what a person walks in the time since the previous frame
  (``walk_speed_mps`` in box heights of a ``height_m`` person, times ``reach_margin`` for
  perspective): between two frames nothing is observed, so at 1 fps a person crosses open
  floor unseen and may be behind a cabinet 1.5 m away in the next frame,
* and losing every cell the camera, working (a fresh frame, no STOP fault of the camera or the
  detector), has seen with no person box there for ``clear_time`` without a break. So the
  area follows a hidden person at walking speed through everything the camera does not see
  free (behind fixtures, behind other persons, through a camera fault) and nowhere else.

A zone is held while a lost person's area touches it; the hold ends when the area no longer
does (the area itself ends when it is empty). Nothing else ends it: a new person appearing
where the lost one was is a name (``monitor.tracking.tracks``), never evidence that the lost one is
gone; a camera in fault sees nothing free, so the area grows while the fault lasts.

Cells are foot positions on a grid over the image (``FootGrid``: ``cells_across`` columns of
square cells). A cell is *hidden* when no person standing there could be seen by the camera
(``monitor.zones.visibility``: behind a declared occluder or the robot base, or inside a mask
zone): a hidden cell is never seen free, so an area that reaches behind a cabinet stays there
until an operator confirms the cell clear.

Pure numpy on small grids (48 x 27 cells at 16:9): a few microseconds a step per area, plus one
zone check of the hypothetical persons on the area's cells (cached per zone set).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from monitor.tracking.foot_grid import FEET_BAND, FootGrid, carried_cells, grow
from monitor.types import ZoneReport

HOLD_KINDS = frozenset({"protective", "warning"})
ZonesOf = Callable[[np.ndarray], ZoneReport]
# floor points (N, 2) m -> (N,) bool: seen free for clear_time by another working camera
FreeElsewhere = Callable[[np.ndarray], np.ndarray]
# pixels (N, 2) -> (floor xy (N, 2), located (N,)): this camera's calibration
ToFloor = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class CellZones:
    """The zone checks of the hypothetical persons on an area's cells: ``hidden`` for cells
    no person could be seen on (the full check: a box ending on a fixture's outline may have
    its feet further on), ``seen`` for the others, where the feet stand on the cell in view
    (no cut-off inferred from a fixture's outline or a line of the commissioning reference:
    that placed a person lost 3 m behind the protective zone inside it, issue 46). Called
    as one check, it is the full one."""

    hidden: ZonesOf
    seen: ZonesOf

    def __call__(self, boxes_px: np.ndarray) -> ZoneReport:
        return self.hidden(boxes_px)


@dataclass(frozen=True)
class HeldZone:
    zone_id: str
    kind: str
    speed_scale: float


def union_zones(*groups: Iterable[HeldZone]) -> tuple[HeldZone, ...]:
    """Every zone of the groups once (the lowest speed scale of each), sorted by id."""
    out: dict[str, HeldZone] = {}
    for group in groups:
        for z in group:
            old = out.get(z.zone_id)
            if old is None or z.speed_scale < old.speed_scale:
                out[z.zone_id] = z
    return tuple(sorted(out.values(), key=lambda z: z.zone_id))


@dataclass(frozen=True)
class WhereaboutsConfig:
    """Settings of the lost persons' areas (defaults: a brisk walk, a 1.75 m person)."""

    cells_across: int = 48  # grid columns over the image width (square cells)
    walk_speed_mps: float = 1.5  # a hidden person walks at most this fast
    height_m: float = 1.75  # box height of a person, to turn metres into pixels
    # a person walking towards the camera grows in the image: the reach in pixels of the last
    # box's height is stretched by this much (costs nothing in open view, where cells seen
    # free stop the growth anyway)
    reach_margin: float = 1.5
    below: float = 0.25  # feet hidden by a low fixture: up to this share of the box below it
    max_areas: int = 32  # more lost persons than this on one camera: the newest are merged
    # the bounded life of an area that reaches no hidden cell: the time a person walking at
    # walk_speed_mps needs to cross the camera's seen floor, within these bounds (seconds)
    life_min_s: float = 4.0
    life_max_s: float = 30.0
    # floor a seen person has stood in front of this long without a break is unseen space,
    # as behind a fixture: the bounded life never ends an area that reaches it (a colleague
    # standing still can hide a crouching person for as long as they stand; one walking past
    # uncovers each cell within a second)
    covered_s: float = 2.0
    # a seen person explains a lost one's area ("under seen persons") only when their box is
    # within this factor of the lost person's height: the same person seen again, not a
    # colleague standing nearer the camera with the lost one crouching behind them
    same_size: float = 1.5


@dataclass
class LostArea:
    """Where one lost person could be (cells of the camera's ``FootGrid``)."""

    track_id: int
    lost_since: float  # capture time of the last frame the person was seen in
    box_px: tuple[float, float, float, float]  # the last box
    cells: np.ndarray  # (ny, nx) bool
    updated: float  # time of the last growth
    budget: float = 0.0  # growth owed in cells (fractions carried to the next frame)
    zones: tuple[HeldZone, ...] = ()
    merged: tuple[int, ...] = field(default=())  # other lost tracks folded into this one
    behind: bool = False  # kept where a track stood before its box merged with another
    explained: float | None = None  # since when all of it lies under seen persons' feet
    height_px: float = 0.0  # the person's recent full height (the last box may be partial)
    age_s: float = 0.0  # working time since the loss (the bounded life counts it)
    latest_loss: float | None = None  # the latest loss joined into this area (None: its own)
    ended_by: str = ""  # the rule that ended the area (when it has ended)
    # grows behind seen persons too (False: only behind fixtures; ``monitor.tracking.pairs``)
    behind_persons: bool = True

    @property
    def box_height_px(self) -> float:
        return max(self.box_px[3] - self.box_px[1], self.height_px, 1.0)


class Whereabouts:
    """The areas of one camera's lost persons, and how long each cell has been seen free."""

    def __init__(self, config: WhereaboutsConfig | None = None) -> None:
        self.config = config or WhereaboutsConfig()
        self.grid: FootGrid | None = None
        self.hidden: np.ndarray | None = None  # (ny, nx) bool: never seen free
        self._hidden_key: object = None
        self.free_since: np.ndarray | None = None  # (ny, nx) time, nan: not seen free now
        # (ny, nx) time since when each cell has not been seen free without a break (nan:
        # seen free now): floor a standing person has hidden for ``covered_s``
        self.unseen_since: np.ndarray | None = None
        self.areas: dict[int, LostArea] = {}
        self._free: np.ndarray | None = None  # seen free for clear_time at the last frame
        # not seen free at the last frame although the camera was working: under a seen
        # person's feet band, or where a cut-off box's feet may be
        self._occupied: np.ndarray | None = None
        self._zone_cache: dict[tuple[int, int], tuple[HeldZone, ...]] = {}
        self._zone_key: object = None
        self.last_time: float | None = None  # capture time of the last frame judged
        self._floor: tuple[np.ndarray, np.ndarray] | None = None  # grid centres on the floor
        # areas ended since the last ``take_ended``, each with the rule that ended it
        self.ended: list[tuple[LostArea, str]] = []

    # ---------------------------------------------------------------------------------------
    def view(self, width: int, height: int,
             hidden: Callable[[FootGrid], np.ndarray] | None = None, key: object = None) -> None:
        """The camera's image size and (when ``key`` changes) its hidden cells, given by
        ``hidden(grid) -> (ny, nx) bool`` (``monitor.zones.visibility``)."""
        if self.grid is None or (self.grid.width, self.grid.height) != (width, height):
            self.grid = FootGrid.of(width, height, self.config.cells_across)
            self.free_since = np.full(self.grid.shape, np.nan)
            self.unseen_since = np.full(self.grid.shape, np.nan)
            self.areas.clear()  # another image: cells mean other places (never seen here)
            self._hidden_key = object()
            self._zone_cache.clear()
            self._floor = None
        if key != self._hidden_key or self.hidden is None:
            self.hidden = (np.zeros(self.grid.shape, bool) if hidden is None
                           else np.asarray(hidden(self.grid), bool).reshape(self.grid.shape))
            self._hidden_key = key
            self._zone_cache.clear()  # the check of a cell depends on whether it is hidden

    def take_ended(self) -> list[tuple[LostArea, str]]:
        """The areas ended since the last call, each with the rule that ended it ("seen
        free", "seen again", "bounded life", "confirm-clear", ...)."""
        out, self.ended = self.ended, []
        return out

    def life_s(self, area: LostArea) -> float:
        """The bounded life of ``area``: the time a person walking at ``walk_speed_mps``
        needs to cross the camera's picture where they were lost (the image diagonal in box
        heights of the last box, a ``height_m`` person: further away a person is smaller and
        needs longer), within ``life_min_s`` .. ``life_max_s``."""
        cfg = self.config
        if self.grid is None:
            return cfg.life_max_s
        extent = math.hypot(self.grid.width, self.grid.height) / area.box_height_px \
            * cfg.height_m
        life = extent / max(cfg.walk_speed_mps, 1e-6)
        return float(min(max(life, cfg.life_min_s), cfg.life_max_s))

    def free_now(self) -> np.ndarray | None:
        """(ny, nx) bool: the cells seen free for ``clear_time`` as of the last frame (None:
        no frame yet)."""
        return None if self.grid is None else self._free

    def occupied_now(self) -> np.ndarray | None:
        """(ny, nx) bool: the cells under the persons seen in the last frame (their feet
        band, and down a cut-off box's range): someone may stand hidden right behind them
        (None: no frame yet)."""
        return None if self.grid is None else self._occupied

    def blind(self) -> None:
        """A frame the camera could not judge (detector error): nothing has been seen free."""
        if self.free_since is not None:
            self.free_since[:] = np.nan

    def lose(self, track_id: int, box_px: np.ndarray, last_seen: float,
             behind: bool = False, height_px: float = 0.0,
             feet_bottom_px: float = math.nan, behind_persons: bool = True) -> None:
        """A person lost: their area starts under their last box (joined to an area the same
        track left before). ``behind``: the track is still seen, in a box merged with a
        neighbour's; someone may stand where it stood (only seeing that free ends it).
        ``height_px``: the person's full height in the last frames (the tracker's; a person
        vanishing behind a wall leaves a last box of a head only): the area grows at the
        pace of the taller of it and the last box. ``feet_bottom_px``: the last box was cut
        off, its feet may be down to this row. ``behind_persons`` False: it grows only behind
        fixtures, never behind seen persons (``monitor.tracking.pairs``)."""
        if self.grid is None:
            raise RuntimeError("Whereabouts.lose before view(): the image size is unknown")
        seed = self.grid.cells_under(box_px, self.config.below)
        if math.isfinite(feet_bottom_px):
            x1, _, x2, y2 = (float(v) for v in np.asarray(box_px, np.float64).reshape(4))
            seed |= self.grid.cells_under(np.array([x1, y2, x2, max(y2, feet_bottom_px)]),
                                          0.0, band=1.0)
        box = tuple(float(v) for v in np.asarray(box_px, np.float64).reshape(4))
        old = self.areas.get(track_id)
        if old is not None:
            old.cells |= seed
            old.box_px = box  # type: ignore[assignment]
            old.behind = old.behind or behind
            old.height_px = max(old.height_px, float(height_px))
            return
        self.areas[track_id] = LostArea(track_id, float(last_seen), box,  # type: ignore[arg-type]
                                        seed, float(last_seen), behind=behind,
                                        height_px=float(height_px),
                                        behind_persons=behind_persons)

    def carry(self, track_id: int, lost_box_px: np.ndarray, carrier_box_px: np.ndarray,
              reach_px: float) -> None:
        """A lost track hidden in a seen neighbour's box (the carrier) walks with it: its
        area (a place a merged track stood) takes ``carried_cells``."""
        area = self.areas.get(track_id)
        if area is None or self.grid is None:
            return
        area.cells |= carried_cells(self.grid, lost_box_px, carrier_box_px, reach_px,
                                    self.config.below)
        area.behind = True

    def found(self, track_id: int, clear_view: bool = False, apart: bool = False) -> bool:
        """The lost person's own track is seen again (the tracker's association, never a box
        given the id for being near): the sighting explains the loss while everything the
        area covers is in view (a flicker, a short miss), or when the person is seen again in
        clear view (``clear_view``: the whole box in the image, its feet on cells the camera
        sees), also after walking behind a fixture: the name link says it is the same person.
        The place a merged track stood (``behind``) stays, unless the track swallowed by a
        neighbour's box is seen again in clear view ``apart`` from that box (the neighbour's
        track seen in another box of the same frame: both persons in view) and the area,
        one loss's, reaches no hidden cell. True when the area ended."""
        area = self.areas.get(track_id)
        if area is None or self.hidden is None:
            return False
        if area.behind and not (apart and clear_view and not area.merged
                                and not (area.cells & self.hidden).any()):
            return False
        if not clear_view and (area.cells & self.hidden).any():
            return False
        del self.areas[track_id]
        area.ended_by = "seen again"
        self.ended.append((area, area.ended_by))
        return True

    def came_out(self, track_id: int) -> None:
        """The lost person was seen walking out of their area (``monitor.tracking.exits``):
        the area ends."""
        area = self.areas.pop(track_id, None)
        if area is not None:
            area.ended_by = "seen coming out"
            self.ended.append((area, area.ended_by))

    def drop(self) -> list[LostArea]:
        """An operator confirmed the cell clear: every area ends."""
        dropped = list(self.areas.values())
        self.areas.clear()
        self.ended.extend((a, "confirm-clear") for a in dropped)
        return dropped

    # ---------------------------------------------------------------------------------------
    def update(self, now: float, boxes_px: np.ndarray, working: bool, clear_time: float,
               zones_of: ZonesOf | None, zones_key: object = None,
               free_elsewhere: FreeElsewhere | None = None, to_floor: ToFloor | None = None,
               feet_bottom_px: np.ndarray | None = None,
               settle: Callable[[Whereabouts], None] | None = None) -> None:
        """One frame at ``now``: ``boxes_px`` are the persons seen in it; ``working`` is False
        when the camera's view cannot be trusted (a STOP fault of the camera or detector).
        Then every area grows, loses the cells seen free for ``clear_time``, and learns the
        zones it touches (``zones_of``: the zone check of hypothetical boxes; its answers are
        kept while ``zones_key`` stays the same, None: this frame only). With a calibration
        (``to_floor``) the cells another working camera has seen free for ``clear_time``
        (``free_elsewhere``, on the floor) are removed too: space a working camera sees empty
        is free, whichever camera it is. ``feet_bottom_px`` (per box; NaN: feet in view): the
        lowest image row the feet of a box cut off at the bottom may be on (placed as a range
        towards the camera): the cells down to it are not seen free, and such a person never
        explains a lost person's area (they may stand anywhere there). ``settle``: run once
        the areas have grown and lost what was seen free, before empty areas end and the
        zones are learnt (the pockets' counts, ``monitor.tracking.pockets``)."""
        if self.grid is None or self.free_since is None or self.hidden is None:
            raise RuntimeError("Whereabouts.update before view(): the image size is unknown")
        grid, cfg = self.grid, self.config
        boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
        cut = np.zeros(len(boxes), bool) if feet_bottom_px is None \
            else np.isfinite(np.asarray(feet_bottom_px, np.float64).reshape(-1))
        whole = boxes[~cut]
        under = [grid.cells_under(b, 0.0) for b in whole]  # each feet-in-view box's cells
        heights = whole[:, 3] - whole[:, 1]
        explains = np.logical_or.reduce(under) if under else np.zeros(grid.shape, bool)
        occupied = explains | grid.cells_under(boxes[cut], 0.0)
        if cut.any():  # where the hidden feet may be, below the box, down to the range's end
            below = boxes[cut].copy()
            below[:, 1] = below[:, 3]
            below[:, 3] = np.maximum(below[:, 3], np.asarray(feet_bottom_px)[cut])
            occupied |= grid.cells_under(below, 0.0, band=1.0)
        seen_free = ~self.hidden & ~occupied if working else np.zeros(grid.shape, bool)
        start = np.isnan(self.free_since)
        self.free_since[seen_free & start] = now
        self.free_since[~seen_free] = np.nan
        with np.errstate(invalid="ignore"):
            free = seen_free & (now - self.free_since >= clear_time - 1e-9)
        if self.unseen_since is None or self.unseen_since.shape != grid.shape:
            self.unseen_since = np.full(grid.shape, np.nan)
        self.unseen_since[seen_free] = np.nan
        self.unseen_since[~seen_free & np.isnan(self.unseen_since)] = now
        with np.errstate(invalid="ignore"):
            covered = ~seen_free & ~self.hidden \
                & (now - self.unseen_since >= cfg.covered_s - 1e-9)
        floor = self._floor_points(to_floor)
        for area in self.areas.values():
            dt = max(0.0, now - area.updated)
            reach_px = cfg.walk_speed_mps / cfg.height_m * area.box_height_px \
                * cfg.reach_margin * dt
            area.budget += reach_px / grid.cell_px if math.isfinite(reach_px) else grid.nx
            steps = min(int(area.budget), grid.nx + grid.ny)
            area.budget -= int(area.budget)
            area.age_s = area.age_s + dt if working else 0.0
            young = area.age_s < self.life_s(area) - 1e-9
            # where a person may be that the camera does not show: behind a fixture, behind
            # a seen person (only within the bounded life: nobody walks hidden behind others
            # for ever), anywhere while the camera is in fault. Between two frames nothing
            # is observed, so the area reaches as far as a walk; but a cell the camera shows
            # free now holds nobody it could see, so the area grows only into cells it does
            # not show, never through other persons' trails on open floor
            unseen = self.hidden | (occupied & young & area.behind_persons) if working \
                else np.ones(grid.shape, bool)
            # where a merged track stood does not walk: a person hidden behind a neighbour
            # who moves on is seen (or merges again); it ends once seen free
            grown = grow(area.cells, 0 if area.behind else steps)
            if floor is not None:  # in pixels near the horizon a step is metres: on the floor
                grown = self._within_walk(area.cells, grown, floor,
                                          cfg.walk_speed_mps * cfg.reach_margin * dt)
            area.cells = (area.cells | (grown & unseen)) & ~free
            area.updated = now
            # a ghost: all of it in view, under seen persons' feet or seen empty, for
            # clear_time (a person who flickered out and came back under a new id); not the
            # place a merged track stood, and never one that reaches where the camera cannot
            # see (``shows_only_seen_persons``)
            if working and not area.behind and shows_only_seen_persons(
                    area.cells, self.hidden, _same_size(under, heights, area, cfg.same_size),
                    seen_free):
                area.explained = now if area.explained is None else area.explained
                if now - area.explained >= clear_time - 1e-9:
                    area.cells[:] = False
                    area.ended_by = "under seen persons"
            else:
                area.explained = None
            # the bounded life: an area that reaches no hidden cell (behind a fixture, or
            # behind a person who has stood there for covered_s), past the time a walker
            # needs to leave the seen floor, holds nobody who could not have been seen
            if not young and area.cells.any() \
                    and not (area.cells & (self.hidden | covered)).any():
                area.cells[:] = False
                area.ended_by = "bounded life"
        self._free, self._occupied, self.last_time = free, occupied, now
        if free_elsewhere is not None and floor is not None:
            self._clear_elsewhere(free_elsewhere, floor)
        if settle is not None:
            settle(self)
        for tid in [t for t, a in self.areas.items() if not a.cells.any()]:
            area = self.areas.pop(tid)
            self.ended.append((area, area.ended_by or "seen free"))
        self._merge_alike()
        if zones_key is None or zones_key != self._zone_key:
            self._zone_cache.clear()
        self._zone_key = zones_key
        self._zones(zones_of)

    def floor_cells(self) -> np.ndarray | None:
        """(ny, nx) bool: the cells whose foot position lies on the floor (a calibrated
        camera, as of its last frame; None: not known)."""
        if self._floor is None or self.grid is None:
            return None
        return self._floor[1].reshape(self.grid.shape)

    def _floor_points(self, to_floor: ToFloor | None
                      ) -> tuple[np.ndarray, np.ndarray] | None:
        """The grid's foot positions on the floor (a calibrated camera; None: not)."""
        if to_floor is None or self.grid is None:
            return None
        if self._floor is None:
            xy, located = to_floor(self.grid.centres())
            xy = np.asarray(xy, np.float64)
            self._floor = (xy, np.asarray(located, bool) & np.all(np.isfinite(xy), axis=1))
        return self._floor

    def _within_walk(self, old: np.ndarray, grown: np.ndarray,
                     floor: tuple[np.ndarray, np.ndarray], reach_m: float) -> np.ndarray:
        """The grown cells whose floor point lies within ``reach_m`` (plus a cell's own
        size, 0.3 m) of one of the old cells' floor points; a cell no floor point of the old
        ones reaches (above the horizon, or from an area with no floor point) is left out."""
        xy, located = floor
        new = np.flatnonzero((grown & ~old).ravel())
        if not len(new):
            return grown
        src = np.flatnonzero(old.ravel() & located)
        out = old.copy()
        if not len(src):
            return out
        cand = new[located[new]]
        if len(cand):
            d = np.min(np.linalg.norm(xy[cand][:, None, :] - xy[src][None, :, :], axis=2),
                       axis=1)
            out.flat[cand[d <= reach_m + 0.3]] = True
        return out

    def _clear_elsewhere(self, free_elsewhere: FreeElsewhere,
                         floor: tuple[np.ndarray, np.ndarray]) -> None:
        """Remove the area cells whose floor point another working camera has seen free."""
        if self.grid is None or not self.areas:
            return
        xy, located = floor
        for area in self.areas.values():
            idx = np.flatnonzero(area.cells.ravel() & located)
            if len(idx):
                cleared = np.asarray(free_elsewhere(xy[idx]), bool)
                area.cells.flat[idx[cleared]] = False

    def _merge_alike(self) -> None:
        """An area within another (ghosts of one person following them) joins it, named by
        the longest lost, when the union lives no longer than the area that covers it
        (``_joins``); past ``max_areas`` the newest join the oldest. The union keeps every
        cell either could be on."""
        order = sorted(self.areas.values(), key=lambda a: (a.lost_since, a.track_id))
        kept: list[LostArea] = []
        for area in order:
            same = next((k for k in kept if _joins(k, area)), None)
            if same is None and len(kept) < self.config.max_areas:
                kept.append(area)
                continue
            into = same if same is not None else kept[0]
            into.cells |= area.cells
            # the union lives as long as its youngest loss (a fresh loss never ends early)
            into.age_s = min(into.age_s, area.age_s)
            into.latest_loss = max(into.latest_loss or into.lost_since,
                                   area.latest_loss or area.lost_since)
            into.budget = max(into.budget, area.budget)
            into.height_px = max(into.height_px, area.height_px)
            into.merged = (*into.merged, area.track_id, *area.merged)
        self.areas = {a.track_id: a for a in kept}

    def zone_cells(self, area: LostArea, kinds: Iterable[str] = HOLD_KINDS) -> np.ndarray:
        """(ny, nx) bool: the cells of ``area`` a person standing on would be in a zone of
        one of ``kinds`` (the zone answers of its last frame): where the hold is (what a
        diagnostic asks of a refusal, ``benchmarks/refusals.py``)."""
        out = np.zeros_like(area.cells)
        wanted = set(kinds)
        hq = _height_bucket(area.box_height_px)
        for i in np.flatnonzero(area.cells.ravel()):
            if any(z.kind in wanted for z in self._zone_cache.get((int(i), hq), ())):
                out.flat[i] = True
        return out

    def _zones(self, zones_of: ZonesOf | None) -> None:
        """Each area's zones: those a person standing on one of its cells would be in."""
        if zones_of is None or self.grid is None:
            for area in self.areas.values():
                area.zones = ()
            return
        centres = self.grid.centres()
        wanted: dict[tuple[int, int], np.ndarray] = {}
        per_area: dict[int, list[tuple[int, int]]] = {}
        for area in self.areas.values():
            hq = _height_bucket(area.box_height_px)
            keys = [(int(i), hq) for i in np.flatnonzero(area.cells.ravel())]
            per_area[area.track_id] = keys
            for key in keys:
                if key not in self._zone_cache and key not in wanted:
                    cx, cy = centres[key[0]]
                    h = float(key[1])
                    wanted[key] = np.array([cx - 0.2 * h, cy - h, cx + 0.2 * h, cy])
        hidden = self.hidden.ravel() if self.hidden is not None \
            else np.zeros(self.grid.nx * self.grid.ny, bool)
        checks = ((zones_of.hidden, [k for k in wanted if hidden[k[0]]]),
                  (zones_of.seen, [k for k in wanted if not hidden[k[0]]])) \
            if isinstance(zones_of, CellZones) else ((zones_of, list(wanted)),)
        for check, keys in checks:
            if not keys:
                continue
            report = check(np.stack([wanted[k] for k in keys]))
            found: dict[int, list[HeldZone]] = {}
            for hit in report.hits:
                if 0 <= hit.person < len(keys) and not hit.lost and hit.kind in HOLD_KINDS:
                    found.setdefault(hit.person, []).append(
                        HeldZone(hit.zone_id, hit.kind, float(hit.speed_scale)))
            for row, key in enumerate(keys):
                self._zone_cache[key] = union_zones(found.get(row, ()))
        for area in self.areas.values():
            area.zones = union_zones(*(self._zone_cache[k] for k in per_area[area.track_id]))


def shows_only_seen_persons(cells: np.ndarray, hidden: np.ndarray, explains: np.ndarray,
                            seen_free: np.ndarray) -> bool:
    """In this frame the camera shows nothing at the area's ``cells`` but seen persons: all
    of them under seen persons' feet (``explains``: feet in view), or all of them seen with
    nobody there (``seen_free``: the detector missed the person it showed there a frame
    ago), none hidden. A lost person standing in such an area is hidden right behind a seen
    person or missed in open view, the cases the rules "under seen persons" and "seen free"
    end after clear_time each: a frame with the whole area empty (a detector's flicker) does
    not restart that time. An area partly seen empty, partly under a person (trailing a
    person walking on) does: someone may walk hidden behind them (the bounded life ends
    that). Under a box cut off at its feet (they may stand anywhere down its range) the
    camera does not show."""
    if not cells.any() or (cells & hidden).any():
        return False
    return not (cells & ~explains).any() or not (cells & ~seen_free).any()


def _same_size(under: list[np.ndarray], heights: np.ndarray, area: LostArea,
               factor: float) -> np.ndarray:
    """(ny, nx) bool: the cells under the feet-in-view boxes whose height is within
    ``factor`` of the lost person's (``under``: each box's cells, ``heights`` theirs)."""
    h = area.box_height_px
    out = np.zeros_like(area.cells)
    for cells, bh in zip(under, heights, strict=True):
        if h / factor <= bh <= h * factor:
            out |= cells
    return out


def _joins(into: LostArea, area: LostArea) -> bool:
    """``area`` may join ``into`` without making a hold outlive its bounded life: one lies
    within the other, and the union's life (its youngest member's) is no longer than the
    life of the one that covers the union. A fresh loss inside an old person's larger area
    stays on its own: joined, the old area would live as long as the fresh loss (in a busy
    scene a flicker a second kept one person's area alive for ever, issue 46)."""
    # a place a merged track stood does not walk and no sighting ends it, a lost person's
    # area walks (and one kept only behind fixtures): joined, one would take the other's rule
    if (into.behind, into.behind_persons) != (area.behind, area.behind_persons) \
            or not _nested(into.cells, area.cells):
        return False
    if area.age_s >= into.age_s - 1e-9:  # not younger: the union lives no longer
        return True
    # the younger covers the union (the older lies within it): the union is the younger
    return bool(np.array_equal(into.cells & area.cells, into.cells))


def _nested(a: np.ndarray, b: np.ndarray) -> bool:
    """One set of cells lies within the other."""
    both = a & b
    return bool(np.array_equal(both, a) or np.array_equal(both, b))


def _height_bucket(h: float) -> int:
    """Box heights in steps of 8 px (the zone answers of hypothetical persons are cached)."""
    return max(8, round(h / 8.0) * 8)


# the foot grid's names (monitor.tracking.foot_grid), where callers have always found them
__all__ = ["FEET_BAND", "HOLD_KINDS", "CellZones", "FootGrid", "FreeElsewhere", "HeldZone",
           "LostArea", "ToFloor", "Whereabouts", "WhereaboutsConfig", "ZonesOf",
           "carried_cells", "grow", "shows_only_seen_persons", "union_zones"]
