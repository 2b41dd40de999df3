"""What changed since commissioning: objects put into the protective and warning zones after the
camera's reference was taken (a crate, a trolley, a parts bin) hide the floor behind them.

The laser scanner's answer, for a camera: watch the reference contour and stop when the scene
changes. Each frame the image regions of the protective and warning volumes (their image
hulls from the floor up, at an analysis width of ``ANALYSIS_WIDTH`` px) are compared with the
commissioning reference, the frame's lighting first matched to it (gain and offset fitted on
the unchanged pixels, as the watch zones do: ``monitor.health.scene``), so that a light switched
down to x0.7 changes nothing. Pixels under a detected person's box (grown by a margin) say
nothing: persons are not objects. A pixel that has stayed changed for ``persist_s`` is a
*lasting* change; a connected region of lasting change of at least ``min_area`` whose bottom
lies on a zone's floor is an **object** standing there:

* the floor it hides is unseen: the camera's hidden foot cells (``hidden_cells``) gain the
  cells from its top row down to its bottom row under its columns, so a person lost behind it
  is held until an operator confirms the cell clear (docs/tracking.md);
* an alert (``object_placed``, with a snapshot that outlines it) names the camera, the zone and
  the floor place once, when it appears;
* while it stands in a protective zone unaccepted, a STOP fault (``object_in_zone``) refuses
  every reset, until an operator accepts it by its own signed request (``monitor objects
  accept --camera C --zone Z``: ``monitor.wire.object_accepts``, judged by
  ``monitor.health.acceptance``, alerted and so in the events file); a reset, confirm-clear
  or not, never accepts an object. Accepted, it stays an occluder declared at run time (its
  shadow stays held until seen free) but no longer holds the cell by itself;
* when the region is back to the reference for ``clear_s`` the object is gone.

Without a reference nothing is compared (the first frame would make any object part of the
scene): the service says so at start and in its status.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from monitor.health.analysis import analysis_bgr
from monitor.health.draw import encode_jpeg
from monitor.types import Alert, Fault
from monitor.wire.object_accepts import accept_command
from monitor.zones import volume_outline_m
from monitor.zones.masks import zone_regions_px
from monitor.zones.schema import RobotBaseSpec

ANALYSIS_WIDTH = 320
OBJECT_PLACED = "object_placed"
OBJECT_GONE = "object_gone"
OBJECT_IN_ZONE = "object_in_zone"
VIEW_CHANGED = "view_changed"


@dataclass(frozen=True)
class ObjectConfig:
    """Thresholds of the object check (defaults: a crate of 0.4 m at 7 m on a 640 px camera is
    about 300 analysis pixels; a person standing still is excluded by their box)."""

    diff: float = 30.0  # grey levels (largest channel) after the lighting fit
    persist_s: float = 3.0  # changed this long without a break: a lasting change
    clear_s: float = 2.0  # an object unchanged against the reference this long is gone
    min_area_px: float = 120.0  # analysis pixels of one lasting region
    person_margin: float = 0.2  # person boxes grown by this share of their size
    # this share of the zones' image region changed for good: no object can be told from the
    # rest (it would merge into one region that stands on no zone's floor and be missed), so
    # the view itself is no longer the commissioned one: a STOP fault (``view_changed``)
    view_share: float = 0.5


@dataclass(frozen=True)
class ZoneRegion:
    """A protective or warning volume on one camera: its image hull from the floor up (where
    an object in it shows) and its floor footprint's image polygon (where it stands)."""

    zone_id: str
    kind: str
    hull_px: np.ndarray  # (K, 2) full-resolution pixels
    floor_px: np.ndarray  # (M, 2)


@dataclass
class SceneObject:
    """One object found in a zone: its box (full-resolution pixels), the floor point under
    its bottom centre (None: not placeable), the zones it stands in."""

    object_id: int
    box_px: tuple[int, int, int, int]
    floor_m: tuple[float, float] | None
    zone_ids: tuple[str, ...]
    protective: bool
    since: float
    accepted_by: str | None = None
    last_changed: float = 0.0
    accepted_at: float | None = None  # the caller's clock (monotonic, or the video's)
    accepted_wall: float | None = None  # the acceptance's Unix time (for the status)

    def place(self) -> str:
        where = "" if self.floor_m is None else \
            f" at x {self.floor_m[0]:.1f} m, y {self.floor_m[1]:.1f} m"
        return f"{', '.join(self.zone_ids)}{where} (image box {list(self.box_px)})"


@dataclass
class ZoneObjects:
    """The object check of one camera (module docstring). ``to_floor``: the calibration's
    ``pixel_to_floor`` (None: objects are placed in the image only)."""

    camera_id: str
    regions: Sequence[ZoneRegion] = field(repr=False)
    reference_bgr: np.ndarray = field(repr=False)
    to_floor: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = \
        field(default=None, repr=False)
    config: ObjectConfig = field(default_factory=ObjectConfig)
    # image regions (full-resolution polygons) never compared: the cell's mask zones (a robot
    # arm that moves in view is masked there)
    exclude_px: Sequence[np.ndarray] = field(default=(), repr=False)
    objects: dict[int, SceneObject] = field(default_factory=dict)
    version: int = 0  # changes whenever the set of objects (their boxes) changes
    view_changed_since: float | None = None  # when most of the watched view changed for good

    def __post_init__(self) -> None:
        h, w = self.reference_bgr.shape[:2]
        self._size = (w, h)
        self._scale = w / ANALYSIS_WIDTH  # full-resolution px per analysis px
        small = (ANALYSIS_WIDTH, max(1, round(h / self._scale)))
        self._small = small
        # the reference in the analysis image the camera's health checks make of each frame
        # (monitor/health/analysis.py), so this watch judges the frame's own copy (issue 49)
        self._ref_u8 = analysis_bgr(self.reference_bgr, small)
        self._ref = self._ref_u8.astype(np.float32)
        mask = np.zeros((small[1], small[0]), np.uint8)
        for r in self.regions:
            cv2.fillPoly(mask, [np.round(r.hull_px / self._scale).astype(np.int32)], 1)
        for poly in self.exclude_px:
            cv2.fillPoly(mask, [np.round(np.asarray(poly) / self._scale).astype(np.int32)], 0)
        self._watch = mask.astype(bool)
        # each zone's floor as the analysis image shows it (what an object may stand on or hide)
        self._floors = {}
        for r in self.regions:
            floor = np.zeros_like(mask)
            cv2.fillPoly(floor, [np.round(r.floor_px / self._scale).astype(np.int32)], 1)
            self._floors[r.zone_id] = floor.astype(bool) | self._floors.get(r.zone_id, False)
        self._since = np.full(mask.shape, np.nan)  # when each pixel started to differ
        self._next_id = 1

    # ---------------------------------------------------------------------------------------
    def check(self, image_bgr: np.ndarray, person_boxes_px: np.ndarray, now: float,
              camera_ok: bool = True, analysis: np.ndarray | None = None) -> list[Alert]:
        """One frame: update the lasting changes and the objects; the alerts of objects that
        appeared or went. Without ``camera_ok`` (an unsound image) nothing is decided.
        ``analysis``: this frame's analysis image as the camera's health checks made it
        (``HealthReport.analysis_bgr``), used when it has this watch's size (the same pixels
        it would make itself: reading the full frame again cost 2.4 ms at 1080p)."""
        if not camera_ok or not self._watch.any():
            return []
        h, w = image_bgr.shape[:2]
        sw, sh = self._small
        if (analysis is not None and (w, h) == self._size and analysis.dtype == np.uint8
                and analysis.shape == (sh, sw, 3)):
            small = analysis
        else:
            if (w, h) != self._size:
                image_bgr = cv2.resize(image_bgr, self._size, interpolation=cv2.INTER_AREA)
            small = analysis_bgr(image_bgr, self._small)
        free = self._watch.copy()
        for x1, y1, x2, y2 in np.asarray(person_boxes_px, np.float64).reshape(-1, 4):
            m = self.config.person_margin
            gx, gy = m * (x2 - x1), m * (y2 - y1)
            a = np.floor(np.array([x1 - gx, y1 - gy]) / self._scale).astype(int)
            b = np.ceil(np.array([x2 + gx, y2 + gy]) / self._scale).astype(int)
            free[max(a[1], 0):max(b[1], 0), max(a[0], 0):max(b[0], 0)] = False
        changed = self._changed(small, free)
        # a pixel under a person says nothing: its streak is kept, neither broken nor begun
        self._since[free & ~changed] = np.nan
        start = free & changed & np.isnan(self._since)
        self._since[start] = now
        with np.errstate(invalid="ignore"):
            lasting = (now - self._since >= self.config.persist_s - 1e-9) & self._watch
        return self._view(lasting, free, now) + \
            self._objects(lasting, changed | ~free, now, image_bgr)

    def _view(self, lasting: np.ndarray, free: np.ndarray, now: float) -> list[Alert]:
        """Whether most of the watched view has changed for good (``view_share`` of the
        pixels a person does not cover): a lighting the fit cannot match, a repainted floor,
        a tarpaulin over the cell. The objects in it cannot be told apart, so the view is not
        the commissioned one: until it matches again, a STOP fault (``faults``)."""
        looked = int((free & self._watch).sum())
        share = float((lasting & free).sum()) / looked if looked else 0.0
        was = self.view_changed_since is not None
        if share >= self.config.view_share:
            if not was:
                self.view_changed_since = now
                return [Alert(VIEW_CHANGED, "warning", f"{self.camera_id}: {share:.0%} of the "
                              "zones' image differs from the commissioning reference for good "
                              "(light, floor or cover changed): objects cannot be told apart, "
                              "the cell is held until the view matches the reference again or "
                              "a new reference is taken", self.camera_id, now, None,
                              {"share": round(share, 3)})]
        elif was and share < self.config.view_share / 2:
            self.view_changed_since = None
            return [Alert(VIEW_CHANGED, "info", f"{self.camera_id}: the zones' image matches "
                          "the commissioning reference again", self.camera_id, now, None,
                          {"share": round(share, 3)})]
        return []

    def _changed(self, small: np.ndarray, free: np.ndarray) -> np.ndarray:
        """The watched pixels that differ from the reference (largest channel) by more than
        ``diff`` after the frame's lighting is matched to it (``small``: the frame's analysis
        image, uint8)."""
        if free.sum() < 50:
            return np.zeros(free.shape, bool)
        # np.compress: the same pixels in the same order as boolean indexing, ~3x cheaper
        visible = free.ravel()
        cur = np.compress(visible, small.reshape(-1, 3), axis=0).ravel()
        bg = np.compress(visible, self._ref_u8.reshape(-1, 3), axis=0).ravel()
        gain, offset = lighting_fit(cur, bg, 2 * self.config.diff)
        predicted = gain * self._ref + offset
        excess = np.abs(small.astype(np.float32) - predicted)
        # channel by channel: numpy's reductions over a last axis of 3 are slow (2 ms against
        # 0.15 ms at 320x180 here), the maxima the same
        excess = np.maximum(np.maximum(excess[..., 0], excess[..., 1]), excess[..., 2])
        return (excess > self.config.diff) & self._watch

    def _objects(self, lasting: np.ndarray, not_back: np.ndarray, now: float,
                 image_bgr: np.ndarray) -> list[Alert]:
        cfg = self.config
        alerts: list[Alert] = []
        found: list[tuple[tuple[int, int, int, int], tuple[str, ...]]] = []
        # no lasting change (the usual frame): no region, and no labelling to pay for
        n, labels, stats, _ = cv2.connectedComponentsWithStats(lasting.astype(np.uint8), 8) \
            if lasting.any() else (1, None, None, None)
        for k in range(1, n):
            x, y, w, h, area = (int(v) for v in stats[k])
            if area >= cfg.min_area_px:
                s = self._scale
                box = (math.floor(x * s), math.floor(y * s), math.ceil((x + w) * s),
                       math.ceil((y + h) * s))
                found.append((box, self._zones_of(box, labels[y:y + h, x:x + w] == k, (x, y))))
        for box, zones in found:
            old = next((o for o in self.objects.values() if _overlap(o.box_px, box)), None)
            if old is not None:
                old.last_changed = now
                if old.box_px != box:
                    old.box_px = box
                    self.version += 1
                if self._grown(old, zones):
                    alerts.append(self._placed_alert(old, image_bgr, now))
                continue
            obj = self._new(box, zones, now)
            if obj is None:
                continue
            self.objects[obj.object_id] = obj
            self.version += 1
            alerts.append(self._placed_alert(obj, image_bgr, now))
        for oid in list(self.objects):
            obj = self.objects[oid]
            x1, y1, x2, y2 = (round(v / self._scale) for v in obj.box_px)
            if not not_back[y1:y2, x1:x2].any():
                if now - obj.last_changed >= cfg.clear_s - 1e-9:
                    del self.objects[oid]
                    self.version += 1
                    alerts.append(Alert(OBJECT_GONE, "info", f"{self.camera_id}: the object "
                                        f"in {obj.place()} is gone (the view matches the "
                                        "reference again)", self.camera_id, now, None,
                                        {"zones": list(obj.zone_ids), "box_px": list(obj.box_px)}))
            else:
                obj.last_changed = now
        return alerts

    def _zones_of(self, box: tuple[int, int, int, int], part: np.ndarray,
                  at: tuple[int, int]) -> tuple[str, ...]:
        """The zones a changed region stands in or hides: those whose floor its bottom centre
        is on, and those whose floor's image it covers (``part``: its analysis pixels in its
        own box, whose corner is ``at``). A crate in front of the protective zone, or one that
        merged with a larger change whose foot is elsewhere, still hides that floor."""
        foot = ((box[0] + box[2]) / 2, box[3])
        x, y = at
        h, w = part.shape
        out = []
        for r in self.regions:
            on = cv2.pointPolygonTest(r.floor_px.astype(np.float32).reshape(-1, 1, 2),
                                      (float(foot[0]), float(foot[1])), True) >= -2.0
            if on or (self._floors[r.zone_id][y:y + h, x:x + w] & part).any():
                out.append(r.zone_id)
        return tuple(dict.fromkeys(out))

    def _is_protective(self, zones: Sequence[str]) -> bool:
        return any(r.kind == "protective" for r in self.regions if r.zone_id in zones)

    def _grown(self, obj: SceneObject, zones: tuple[str, ...]) -> bool:
        """An object's region reaches more zones than before: they are added; one that now
        reaches a protective zone it was not accepted in holds the cell again (an operator
        accepted what stood there then, not what stands there now). True: it reaches a
        protective zone now (said again, as a new object)."""
        more = tuple(z for z in zones if z not in obj.zone_ids)
        if not more:
            return False
        obj.zone_ids = obj.zone_ids + more
        self.version += 1
        if not self._is_protective(more):
            return False
        obj.protective = True
        obj.accepted_by = obj.accepted_at = obj.accepted_wall = None
        return True

    def _new(self, box: tuple[int, int, int, int], zones: tuple[str, ...], now: float
             ) -> SceneObject | None:
        """An object at ``box`` if it stands on or hides a zone's floor (``_zones_of``; else
        None: a change up in the air, on the wall or the robot, is not an object)."""
        if not zones:
            return None
        foot = np.array([[(box[0] + box[2]) / 2, box[3]]], float)
        floor = None
        if self.to_floor is not None:
            xy, ok = self.to_floor(foot)
            floor = (float(xy[0][0]), float(xy[0][1])) if ok[0] else None
        obj = SceneObject(self._next_id, box, floor, zones, self._is_protective(zones), now,
                          None, now)
        self._next_id += 1
        return obj

    def _placed_alert(self, obj: SceneObject, image_bgr: np.ndarray, now: float) -> Alert:
        img = image_bgr.copy()
        x1, y1, x2, y2 = obj.box_px
        cv2.rectangle(img, (x1 - 3, y1 - 3), (x2 + 3, y2 + 3), (0, 0, 255), 3)
        cv2.putText(img, f"{self.camera_id}: object in {', '.join(obj.zone_ids)}", (10, 30),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 255), 2)
        what = "protective" if obj.protective else "warning"
        message = (f"{self.camera_id}: an object not in the commissioning reference stands "
                   f"in {what} zone {obj.place()}: the floor behind it is not seen"
                   + ("; resets are refused until an operator has looked and accepts it: "
                      + accept_command(self.camera_id, obj.zone_ids[0])
                      if obj.protective else ""))
        return Alert(OBJECT_PLACED, "warning", message, self.camera_id, now,
                     encode_jpeg(img, 1280, 80),
                     {"zones": list(obj.zone_ids), "box_px": list(obj.box_px),
                      "floor_m": list(obj.floor_m) if obj.floor_m else None})

    # ---------------------------------------------------------------------------------------
    def faults(self) -> list[Fault]:
        """STOP faults of the unaccepted objects in protective zones, and of a view that
        changed for good (``_view``)."""
        view = [] if self.view_changed_since is None else [Fault(
            VIEW_CHANGED, f"{self.camera_id}: most of the zones' image differs from the "
            f"commissioning reference since {self.view_changed_since:.1f} s (objects cannot be "
            "told apart: restore the view, or take a new reference after looking)", True,
            self.camera_id)]
        return view + [Fault(OBJECT_IN_ZONE, f"{self.camera_id}: object in {o.place()} since "
                      f"{o.since:.1f} s, not in the commissioning reference (look at it, then "
                      f"accept it: {accept_command(self.camera_id, self._protective_zone(o))})",
                      True, self.camera_id)
                for o in self.objects.values() if o.protective and o.accepted_by is None]

    def _protective_zone(self, obj: SceneObject) -> str:
        kinds = {r.zone_id: r.kind for r in self.regions}
        return next((z for z in obj.zone_ids if kinds.get(z) == "protective"), obj.zone_ids[0])

    def accept(self, zone_id: str, operator: str, now: float, wall: float
               ) -> list[SceneObject]:
        """An operator looked and accepts the objects standing in ``zone_id`` now (those not
        accepted yet); the ones accepted are returned."""
        out = [o for o in self.objects.values()
               if o.accepted_by is None and zone_id in o.zone_ids]
        for o in out:
            o.accepted_by, o.accepted_at, o.accepted_wall = operator, now, wall
        return out

    def hidden_cells(self, centres_px: np.ndarray, unaccepted_only: bool = False
                     ) -> np.ndarray:
        """(N,) bool: foot positions (full-resolution pixels) behind or in an object: under
        its columns, from its top row down to its bottom row (a person standing there shows
        less than the box's height above it). ``unaccepted_only``: behind the objects no
        operator has accepted yet."""
        pts = np.asarray(centres_px, float).reshape(-1, 2)
        out = np.zeros(len(pts), bool)
        for o in self.objects.values():
            if unaccepted_only and o.accepted_by is not None:
                continue
            x1, y1, x2, y2 = o.box_px
            out |= (pts[:, 0] >= x1) & (pts[:, 0] <= x2) & (pts[:, 1] >= y1) \
                & (pts[:, 1] <= y2)
        return out


def carry_over(old: ZoneObjects, new: ZoneObjects) -> None:
    """A zone apply: ``new`` (the new zones' watch of the same camera and reference) takes
    over how long each pixel has differed where both watch it, so an object standing there is
    found again at its next frame, in the zones it stands in now, not after another
    ``persist_s``; pixels newly watched start afresh. Acceptances are not carried: an operator
    accepted an object in the zones as they were (the refusal names the command again)."""
    if old._since.shape != new._since.shape:
        return
    both = old._watch & new._watch
    new._since[both] = old._since[both]
    new._next_id = old._next_id
    new.version = old.version + 1


def lighting_fit(cur: np.ndarray, bg: np.ndarray, tolerance: float) -> tuple[float, float]:
    """The gain and offset that map the reference's levels ``bg`` onto the frame's ``cur``
    (uint8, the same pixels), fitted by least squares on the pixels a median offset already
    explains within ``tolerance`` (a changed region does not bend the fit).

    The values are whole grey levels, so this is exact integer arithmetic where the plain
    form (np.median of the differences, np.cov of their float copies: 0.9 of its 1.6 ms at
    320x180) rounds: the median from a histogram of the 511 possible differences, the sums
    and products in int64 (255**2 * 1e5 pixels is 6.5e9)."""
    d = cur.astype(np.int16) - bg.astype(np.int16)
    n = len(d)
    below = np.cumsum(np.bincount(d + 255, minlength=511))  # differences <= k - 255
    # np.median: the middle one, or the mean of the two middle ones
    upper = int(np.searchsorted(below, n // 2 + 1)) - 255
    lower = upper if n % 2 else int(np.searchsorted(below, n // 2)) - 255
    offset = (lower + upper) / 2
    # |d - offset| < tolerance in whole half levels (int16, no float copy): the same pixels
    use = np.abs(2 * d - (lower + upper)) <= math.ceil(2 * tolerance) - 1
    m = int(np.count_nonzero(use))
    if m < 30:
        return 1.0, offset
    # int64 products and sums (np.dot of float64 here: 4 ms on a loaded host, BLAS threads)
    x, y = bg[use].astype(np.int64), cur[use].astype(np.int64)
    sx, sy = int(x.sum()), int(y.sum())
    var_m2 = m * int((x * x).sum()) - sx * sx  # m**2 times the variance, exact
    gain = 1.0
    if var_m2 >= 25 * m * m:
        cov_m2 = m * int((x * y).sum()) - sx * sy
        gain = min(max(cov_m2 / var_m2, 0.5), 2.0)
    return gain, (sy - gain * sx) / m


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def zone_regions(cell, camera_id: str) -> list[ZoneRegion]:
    """The enabled protective and warning volumes of ``cell`` as ``camera_id`` sees them
    (a calibration that projects heights is needed; none otherwise). Zones that follow the
    tool are left out (they move with it)."""
    model = cell.camera_models.get(camera_id)
    if model is None or not model.can_project_3d:
        return []
    out = []
    for z in cell.zones:
        if not (z.enabled and z.is_volume and z.kind in ("protective", "warning")) \
                or getattr(z, "follow", None) is not None:
            continue
        pts = np.concatenate(volume_outline_m(z, cell))
        px, front = model.project(pts)
        if not front.all():
            continue
        bottom = pts[:, 2] <= pts[:, 2].min() + 1e-6
        floor_pts = pts[bottom].copy()
        floor_pts[:, 2] = 0.0
        fpx, _ = model.project(floor_pts)
        out.append(ZoneRegion(z.id, z.kind,
                              cv2.convexHull(px.astype(np.float32)).reshape(-1, 2),
                              cv2.convexHull(fpx.astype(np.float32)).reshape(-1, 2)))
    return out


def objects_of(cell, references) -> dict[str, ZoneObjects]:
    """The object check of every camera of ``cell`` with a reference (``references``: camera
    id -> BGR image, any size with the camera's aspect)."""
    out: dict[str, ZoneObjects] = {}
    if cell is None:
        return out
    for cid, image in (references or {}).items():
        spec = cell.cameras.get(cid)
        regions = zone_regions(cell, cid) if spec is not None else []
        if image is None or not regions:
            continue
        ref = np.asarray(image)
        if (ref.shape[1], ref.shape[0]) != (spec.width, spec.height):
            ref = cv2.resize(ref, (spec.width, spec.height), interpolation=cv2.INTER_AREA)
        model = cell.camera_models.get(cid)
        masks = [p for _, p in zone_regions_px(cell, cid, ("mask",))]
        column = robot_column_px(cell, cid)
        out[cid] = ZoneObjects(cid, regions, ref, model.pixel_to_floor if model else None,
                               exclude_px=[*masks, *([column] if column is not None else [])])
    return out


# the robot moves above its base: its column (the base cylinder up to this height) is no place
# to look for objects (an arm in another pose than on the reference is no crate)
ROBOT_COLUMN_M = 3.0


def robot_column_px(cell, camera_id: str) -> np.ndarray | None:
    """The image hull (full-resolution pixels) of the robot base's cylinder from the floor up
    to ``ROBOT_COLUMN_M`` (None: the camera cannot project it)."""
    model = cell.camera_models.get(camera_id)
    if model is None or not model.can_project_3d:
        return None
    base = cell.spec.robot_base or RobotBaseSpec()
    a = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
    ring = np.c_[base.center_m[0] + base.radius_m * np.cos(a),
                 base.center_m[1] + base.radius_m * np.sin(a)]
    pts = np.r_[np.c_[ring, np.zeros(len(a))], np.c_[ring, np.full(len(a), ROBOT_COLUMN_M)]]
    px, front = model.project(pts)
    if not front.all():
        return None
    return cv2.convexHull(px.astype(np.float32)).reshape(-1, 2)
