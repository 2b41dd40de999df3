"""Every zone is watched or flagged: the part of each protective and warning zone no camera sees.

A person no camera sees cannot cause a STOP. This module samples each enabled protective and
warning volume zone and asks every calibrated camera whether it would see a person there:

* **floor**: a point of the zone's floor is *observed* by a camera when a person of the minimum
  height (``person.height_range_m[0]``) standing there shows their head to it: the head top is in
  front of the camera, projects inside the image with the person's radius to spare on the left
  and right, and the sight line to it passes through no occluder (the declared ``occluder``
  volumes and the robot base, which is always one). Floor inside an occluder's footprint does not
  count (nobody stands in a bench). A person partly hidden is placed from the head
  (monitor/geometry/occlusion.py); one whose head shows to no camera is not seen at all.
* **volume**: points of the zone from the floor up to head height (``height_range_m[1]``),
  observed when some camera sees the point itself (inside its image, sight line free).

``zones validate`` and ``monitor run`` (every ``load_cell``) refuse a protective zone with
unobserved floor unless the zone says ``unobserved_ok: true``; a partly unobserved warning zone
(or an accepted protective one) is a warning, which ``monitor run`` logs at start.

Homography-only cameras see no heights: for them a floor point is observed when it lies in the
image (what they can place), and occluders cannot be used.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from monitor import geometry as geo
from monitor.geometry.occlusion import (
    OccluderVolumes,
    camera_centre_m,
    points_in_volume,
    standable,
)
from monitor.zones.moving import follows_tool, max_zone
from monitor.zones.schema import CellSpec

FLOOR_STEP_M = 0.1  # floor sample spacing (one sample stands for STEP² of floor)
VOLUME_STEP_M = 0.2  # volume sample spacing, horizontal and vertical
MAX_SAMPLES_PER_AXIS = 200  # huge zones are sampled more coarsely, never more finely
SIGHT_SAMPLES = 32  # points tested for occluders along each sight line

Contain = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class ZoneCoverage:
    """How much of one zone no camera observes (areas m², volumes m³, from samples)."""

    zone_id: str
    kind: str
    floor_m2: float  # standable floor of the zone
    unseen_floor_m2: float
    volume_m3: float  # the zone up to head height, occluders left out
    unseen_volume_m3: float
    unseen_floor_xy_m: np.ndarray  # (K, 2) floor samples no camera observes
    sample_m: tuple[float, float] = (FLOOR_STEP_M, FLOOR_STEP_M)  # floor sample cell size
    # floor where no camera sees enough of the smallest posture (``person.crouching_height_m``,
    # ``person.visible_fraction``) for the detector: a lost person there is held until an
    # operator confirms the cell clear (monitor/zones/visibility.py); the unseen floor included
    hidden_crouch_m2: float = 0.0
    hidden_crouch_xy_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def hidden_crouch_fraction(self) -> float:
        return self.hidden_crouch_m2 / self.floor_m2 if self.floor_m2 > 0 else 0.0

    @property
    def unseen_floor_fraction(self) -> float:
        return self.unseen_floor_m2 / self.floor_m2 if self.floor_m2 > 0 else 0.0

    @property
    def unseen_volume_fraction(self) -> float:
        return self.unseen_volume_m3 / self.volume_m3 if self.volume_m3 > 0 else 0.0

    def describe(self) -> str:
        """'1.20 m² (24 %) of its floor and 18 % of its volume up to head height'"""
        text = (f"{self.unseen_floor_m2:.2f} m² ({100 * self.unseen_floor_fraction:.0f} %) of "
                f"its floor and {100 * self.unseen_volume_fraction:.0f} % of its volume up to "
                "head height")
        if len(self.unseen_floor_xy_m):
            half = np.asarray(self.sample_m) / 2
            lo = self.unseen_floor_xy_m.min(axis=0) - half
            hi = self.unseen_floor_xy_m.max(axis=0) + half
            text += (f" (unseen floor within x {lo[0]:.1f}..{hi[0]:.1f} m, "
                     f"y {lo[1]:.1f}..{hi[1]:.1f} m)")
        return text


# --------------------------------------------------------------------------------------------
# What one camera sees


def occluders_contain(occluders: Sequence, meshes: Mapping[str, tuple[np.ndarray, np.ndarray]]
                      ) -> OccluderVolumes:
    return OccluderVolumes(tuple(occluders), meshes)


def _in_image(model: geo.CameraModel, px: np.ndarray, front: np.ndarray,
              margin_px: np.ndarray | float = 0.0) -> np.ndarray:
    ok = front & np.all(np.isfinite(px), axis=1)
    return ok & (px[:, 0] >= margin_px) & (px[:, 0] < model.width - margin_px) \
        & (px[:, 1] >= 0) & (px[:, 1] < model.height)


def sight_free(model: geo.CameraModel, points_m: np.ndarray, contain: Contain) -> np.ndarray:
    """(N,) bool: the sight lines from the camera to the points pass through no occluder (the
    ends excluded); True for every point of a camera that cannot project heights."""
    centre = camera_centre_m(model)
    n = len(points_m)
    if centre is None or not n:
        return np.ones(n, dtype=bool)
    t0, t1 = 1.0 / (SIGHT_SAMPLES + 1), SIGHT_SAMPLES / (SIGHT_SAMPLES + 1)
    if isinstance(contain, OccluderVolumes):  # exactly, over the span the samples covered
        return ~contain.blocks(centre, points_m, t0, t1)
    t = (np.arange(1, SIGHT_SAMPLES + 1) / (SIGHT_SAMPLES + 1))[None, :, None]
    line = centre[None, None, :] + t * (points_m[:, None, :] - centre[None, None, :])
    return ~contain(line.reshape(-1, 3)).reshape(n, SIGHT_SAMPLES).any(axis=1)


def heads_observed(model: geo.CameraModel, floor_xy_m: np.ndarray, head_m: float,
                   radius_m: float, contain: Contain) -> np.ndarray:
    """(N,) bool: this camera sees the head of a person of height ``head_m`` standing at each
    floor point: head top in front, inside the image with ``radius_m`` to spare on either side,
    sight line free of occluders. Homography-only: the floor point is in the image."""
    pts = np.asarray(floor_xy_m, float).reshape(-1, 2)
    n = len(pts)
    heads = np.c_[pts, np.full(n, head_m)]
    px, front = model.project(heads)
    centre = camera_centre_m(model)
    if centre is None or not model.can_project_3d:
        return _in_image(model, px, front)
    # the head's width: both sides, across the viewing direction, must be in the image too
    d = pts - centre[:2]
    norm = np.hypot(d[:, 0], d[:, 1])
    across = np.c_[-d[:, 1], d[:, 0]] / np.where(norm > 1e-9, norm, 1.0)[:, None]
    across[norm <= 1e-9] = (1.0, 0.0)
    sides = np.r_[heads + np.c_[radius_m * across, np.zeros(n)],
                  heads - np.c_[radius_m * across, np.zeros(n)]]
    spx, sfront = model.project(sides)
    inside = _in_image(model, px, front) & _in_image(model, spx[:n], sfront[:n]) \
        & _in_image(model, spx[n:], sfront[n:])
    out = inside.copy()
    if inside.any():
        out[inside] = sight_free(model, heads[inside], contain)
    return out


FIGURE_ROWS = 8  # heights sampled on a person, floor to head
FIGURE_COLUMNS = (-1.0, 0.0, 1.0)  # across the sight line, in person radii


def figure_visible(model: geo.CameraModel, floor_xy_m: np.ndarray, height_m: float,
                   fraction: float, radius_m: float, contain: Contain) -> np.ndarray:
    """(N,) bool: at least ``fraction`` of a person of ``height_m`` standing at each floor
    point is in view of this camera past every occluder: of points spread over the person
    (``FIGURE_ROWS`` heights from the feet to the head, on the axis and ``radius_m`` to
    either side across the sight line) that share has a free sight line. A bench hides the
    lower rows, a cabinet's edge the columns on one side. Image bounds are not judged here
    (``heads_observed`` does); a camera that cannot project heights sees everything."""
    pts = np.asarray(floor_xy_m, float).reshape(-1, 2)
    n = len(pts)
    centre = camera_centre_m(model)
    if centre is None or not model.can_project_3d or not n:
        return np.ones(n, dtype=bool)
    d = pts - centre[:2]
    norm = np.hypot(d[:, 0], d[:, 1])
    across = np.c_[-d[:, 1], d[:, 0]] / np.where(norm > 1e-9, norm, 1.0)[:, None]
    across[norm <= 1e-9] = (1.0, 0.0)
    zs = height_m * (np.arange(FIGURE_ROWS) + 0.5) / FIGURE_ROWS
    zs[-1] = height_m  # the top of the head: what shows first over a fixture
    k = len(FIGURE_COLUMNS)
    offsets = np.asarray(FIGURE_COLUMNS, float) * radius_m
    # (n, columns, rows, 3) points on the person
    xy = pts[:, None, :] + offsets[None, :, None] * across[:, None, :]
    body = np.concatenate([np.repeat(xy[:, :, None, :], len(zs), axis=2),
                           np.broadcast_to(zs[None, None, :, None], (n, k, len(zs), 1))],
                          axis=3).reshape(-1, 3)
    free = sight_free(model, body, contain).reshape(n, -1)
    return free.mean(axis=1) >= fraction - 1e-9


def points_observed(model: geo.CameraModel, points_m: np.ndarray, contain: Contain
                    ) -> np.ndarray:
    """(N,) bool: this camera sees the cell points (in front, in the image, sight line free)."""
    p = np.asarray(points_m, float).reshape(-1, 3)
    px, front = model.project(p)
    out = _in_image(model, px, front)
    if out.any():
        out[out] = sight_free(model, p[out], contain)
    return out


# --------------------------------------------------------------------------------------------
# One zone


def _grid(lo: np.ndarray, hi: np.ndarray, step: float
          ) -> tuple[np.ndarray, tuple[float, float]]:
    """Cell-centred floor samples over [lo, hi] and the size of the cell each stands for."""
    ext = hi - lo
    steps = [max(step, float(e) / MAX_SAMPLES_PER_AXIS) for e in ext]
    xs = lo[0] + steps[0] * (np.arange(max(1, math.ceil(ext[0] / steps[0]))) + 0.5)
    ys = lo[1] + steps[1] * (np.arange(max(1, math.ceil(ext[1] / steps[1]))) + 0.5)
    gx, gy = np.meshgrid(xs, ys)
    return np.c_[gx.ravel(), gy.ravel()], (steps[0], steps[1])


def zone_coverage(zone, spec: CellSpec, models: Mapping[str, geo.CameraModel],
                  meshes: Mapping[str, tuple[np.ndarray, np.ndarray]],
                  floor_step_m: float = FLOOR_STEP_M, volume_step_m: float = VOLUME_STEP_M
                  ) -> ZoneCoverage:
    """Sample a volume zone's floor and its volume up to head height; see the module
    docstring for what counts as observed."""
    occluders = spec.occluder_zones()
    contain = occluders_contain(occluders, meshes)
    h_min, h_max = spec.person.height_range_m
    radius = spec.person.radius_m
    smallest, fraction = spec.person.smallest_height_m, spec.person.needed_fraction
    lo, hi = (np.asarray(v, float) for v in _zone_floor_bounds(zone, meshes))
    z_lo, z_hi = _zone_z_range(zone, meshes)
    if not (np.all(np.isfinite(hi - lo)) and math.isfinite(z_hi - z_lo)):
        raise ValueError("zone bounds are not finite")
    # floor: where a person may stand whose body meets the zone's footprint
    pts, cell = _grid(lo, hi, floor_step_m)
    cell_area = cell[0] * cell[1]
    pts = pts[points_in_volume(zone, np.c_[pts, np.full(len(pts), _zone_mid_height(zone,
                                                                                   meshes))],
                               meshes)]
    pts = pts[standable(occluders, meshes, pts)]
    unseen = np.ones(len(pts), dtype=bool)
    for model in models.values():
        if unseen.any():
            unseen[unseen] = ~heads_observed(model, pts[unseen], h_min, radius, contain)
    # the smallest posture (crouching): enough of it in view for the detector
    crouch = np.ones(len(pts), dtype=bool)
    for model in models.values():
        todo = np.flatnonzero(crouch)
        if not len(todo):
            break
        ok = heads_observed(model, pts[todo], smallest, radius, contain)
        if ok.any():
            ok[ok] = figure_visible(model, pts[todo][ok], smallest, fraction, radius, contain)
        crouch[todo[ok]] = False
    # volume: the zone from the floor (or its bottom) up to head height
    top = min(z_hi, h_max)
    vol_unseen = vol_total = 0.0
    if top > max(z_lo, 0.0):
        base, (vx, vy) = _grid(lo, hi, volume_step_m)
        vcell = vx * vy
        bottom = max(z_lo, 0.0)
        nz = max(1, math.ceil((top - bottom) / volume_step_m))
        dz = (top - bottom) / nz
        zs = bottom + dz * (np.arange(nz) + 0.5)
        vol = np.c_[np.repeat(base, nz, axis=0), np.tile(zs, len(base))]
        vol = vol[points_in_volume(zone, vol, meshes) & ~contain(vol)]
        hidden = np.ones(len(vol), dtype=bool)
        for model in models.values():
            if hidden.any():
                hidden[hidden] = ~points_observed(model, vol[hidden], contain)
        vol_total = len(vol) * vcell * dz
        vol_unseen = float(hidden.sum()) * vcell * dz
    return ZoneCoverage(zone.id, zone.kind, len(pts) * cell_area,
                        float(unseen.sum()) * cell_area, vol_total, vol_unseen, pts[unseen], cell,
                        float(crouch.sum()) * cell_area, pts[crouch])


def _zone_floor_bounds(z, meshes) -> tuple[np.ndarray, np.ndarray]:
    if z.shape == "box":
        lo, hi = np.array(z.min_m[:2]), np.array(z.max_m[:2])
        c, r = (lo + hi) / 2, float(np.hypot(*(hi - lo))) / 2
        return (c - r, c + r) if z.yaw_deg else (lo, hi)
    if z.shape == "extrude":
        p = np.array(z.points_m, float)
        return p.min(axis=0), p.max(axis=0)
    if z.shape == "cylinder":
        c = np.array(z.center_m)
        return c - z.radius_m, c + z.radius_m
    v = meshes[z.id][0]
    return v[:, :2].min(axis=0), v[:, :2].max(axis=0)


def _zone_mid_height(z, meshes) -> float:
    if z.shape == "box":
        return (z.min_m[2] + z.max_m[2]) / 2
    if z.shape in ("extrude", "cylinder"):
        return (z.z_min_m + z.z_max_m) / 2
    v = meshes[z.id][0]
    return float(v[:, 2].min() + v[:, 2].max()) / 2


def _zone_z_range(z, meshes) -> tuple[float, float]:
    if z.shape == "box":
        return float(z.min_m[2]), float(z.max_m[2])
    if z.shape in ("extrude", "cylinder"):
        return float(z.z_min_m), float(z.z_max_m)
    v = meshes[z.id][0]
    return float(v[:, 2].min()), float(v[:, 2].max())


# --------------------------------------------------------------------------------------------
# The zone file's verdict


def coverage_faults(spec: CellSpec, models: Mapping[str, geo.CameraModel],
                    meshes: Mapping[str, tuple[np.ndarray, np.ndarray]]
                    ) -> tuple[list[str], list[str]]:
    """(errors, warnings) about unobserved protective and warning zones (module docstring)."""
    errors: list[str] = []
    warnings: list[str] = []
    for z in spec.zones:
        if z.unobserved_ok is not None and not (z.kind in ("protective", "warning")
                                                and z.is_volume):
            errors.append(f"zone '{z.id}': unobserved_ok is only for protective or warning "
                          "volume zones (an image polygon is seen by its camera)")
    if not models:
        return errors, warnings
    for z in spec.zones:
        if not (z.is_volume and z.enabled and z.kind in ("protective", "warning")):
            continue
        if follows_tool(z):  # it may be anywhere in its maximum volume
            z = max_zone(z)
        try:
            cov = zone_coverage(z, spec, models, meshes)
        except ValueError as exc:
            errors.append(f"zone '{z.id}': coverage cannot be computed: {exc}")
            continue
        if cov.unseen_floor_m2 <= 0:  # heads show everywhere: persons are seen and placed
            continue
        what = f"zone '{z.id}': {cov.describe()} is seen by no camera (outside every image " \
            "or behind an occluder, the robot base included)"
        if z.unobserved_ok:
            warnings.append(f"{what}: accepted by 'unobserved_ok: true'")
        elif z.kind == "protective":
            errors.append(f"{what}: a person there can never cause a STOP; add or move a "
                          "camera, shrink the zone, or set 'unobserved_ok: true' on the zone "
                          "if that is meant")
        else:
            warnings.append(f"{what}: a person there causes no SLOW; add or move a camera "
                            "or shrink the zone")
    return errors, warnings
