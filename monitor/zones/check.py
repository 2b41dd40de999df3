"""The per-frame zone query: which persons are in which zones, how far from the tool."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import fcl
import numpy as np

from monitor import geometry as geo
from monitor.errors import ConfigError, InputError
from monitor.geometry import occlusion as occ
from monitor.types import ZoneHit, ZoneReport
from monitor.zones.files import Cell
from monitor.zones.moving import ToolState
from monitor.zones.moving_check import moving_hits
from monitor.zones.prepare import PreparedCell, tool_object
from monitor.zones.separation import evaluate_separation, pose_in_cell
from monitor.zones.volumes import overlaps, stand_span, swept_person

# --------------------------------------------------------------------------------------------
# The per-frame query


def check_persons(cell: Cell | PreparedCell, camera_id: str, boxes_px: np.ndarray,
                  tool_pose: geo.ToolPose | None = None,
                  tool_speed_mps: float | None = None,
                  foot_uncertainty_px: float = 0.0,
                  foot_band_px: tuple[float, float] | None = None,
                  tool_state: ToolState | None = None,
                  placed: occ.Placement | None = None) -> ZoneReport:
    """Which persons of one frame are in which zones, and how far the nearest is from the tool.

    ``boxes_px`` is (N, 4) x1, y1, x2, y2 in pixels of ``camera_id`` at full resolution.

    Each box is placed on the floor as a *range* of positions (``monitor.geometry.occlusion``): with
    the feet in view, between ``foot_band_px`` = (lo, hi) pixels above the box's bottom edge (the
    detector's box-bottom error; ``foot_uncertainty_px`` alone means (0, that)); with the feet
    possibly hidden (box bottom on an occluder's outline or the image edge, or box shorter than a
    person of the zone file's lowest ``person.height_range_m``), from the head over that height
    range (the feet-in-view answer kept too: a crouching person is short). Floor regions of the zone
    file (``floors:``, platforms and pits) add the positions where the sight lines meet them, and
    the person cylinder then spans every surface the range may stand on. Volume zones test the
    person cylinder (radius + Z_d, person height) swept along the range with FCL: a hit has
    ``distance_m`` 0.0. Image zones with the bottom-centre anchor count the box when any point of
    the feet's pixel range is inside. A person who cannot be placed (feet range reaching the
    horizon) hits every protective and warning volume zone with
    ``distance_m`` None and counts as touching the tool (fail safe).

    Zones that follow the tool (``follow:``) are placed by ``tool_state`` (the pose, its age,
    the pose timeout and the speed): at a fresh pose, grown by S_p at that speed; without a
    fresh pose (``tool_state`` None included) at their ``max_volume`` (monitor/zones/moving.py).

    Mask zones are not applied here: masking happens before boxes are merged (the pipeline's
    rule), so ``masked`` stays empty.

    ``tool_separation_m`` is the smallest distance from a nominal person cylinder (radius, no
    Z_d) anywhere on its range to the tool placed at ``tool_pose`` (None without pose, tool,
    calibration or persons). ``required_separation_m`` is S_p (ISO/TS 15066, including Z_d) for
    ``tool_speed_mps``, or for ``separation.robot_speed_default_mps`` when the speed is unknown;
    None without a tool pose. ``separation_speed_scale`` is min(1, v_max(separation) /
    programmed speed), 0 when the tool is already faster than v_max
    (``monitor.zones.separation``, docs/separation.md). Answers only: no timers, no state.

    ``placed``: ``placement(cell, camera_id, boxes_px, band)`` of exactly these boxes and this
    band when the caller has made it already (the pipeline uses it for the tracks too: one
    placement a frame, not two).
    """
    prep = cell if isinstance(cell, PreparedCell) else cell.prepared
    band = foot_band_px if foot_band_px is not None else (0.0, max(foot_uncertainty_px, 0.0))
    return _check(prep, camera_id, boxes_px, tool_pose, tool_speed_mps, band, tool_state,
                  placed)


def merge_towards_danger(a: ZoneReport, b: ZoneReport) -> ZoneReport:
    """Two answers for the same persons (different assumptions or cameras) as one, the worse
    of both: every hit (a lost-person hold wins over a seen one for the same zone and person,
    then the smaller distance), the smaller tool separation and separation speed scale, the
    larger required separation; masked only if masked in both."""
    hits: dict[tuple[str, int, int | None], ZoneHit] = {}
    for hit in (*a.hits, *b.hits):
        key = (hit.zone_id, hit.person, hit.track_id)
        old = hits.get(key)
        if old is None or _worse(hit, old):
            hits[key] = hit
    seps = [s for s in (a.tool_separation_m, b.tool_separation_m) if s is not None]
    reqs = [s for s in (a.required_separation_m, b.required_separation_m) if s is not None]
    scales = [s for s in (a.separation_speed_scale, b.separation_speed_scale) if s is not None]
    # NaN means "unknown": it must win (the policy STOPs on it), min() would drop it
    scale = None
    if scales:
        scale = math.nan if any(math.isnan(s) for s in scales) else min(scales)
    return ZoneReport(hits=tuple(hits.values()),
                      masked=tuple(sorted(set(a.masked) & set(b.masked))),
                      tool_separation_m=min(seps) if seps else None,
                      required_separation_m=max(reqs) if reqs else None,
                      separation_speed_scale=scale,
                      config_hash=a.config_hash)


def apply_mutes(report: ZoneReport | None, muted: Mapping[str, float | None]
                ) -> ZoneReport | None:
    """The report as the policy sees it while zones are muted (docs/muting.md): a hit in a
    muted zone becomes a warning zone hit at the mute's speed scale (``muted[zone]`` a
    number), or is dropped (None: the zone is not checked while muted). Separation, masks and
    every other zone stay as they are. Applied to the merged report at each decision, never
    to a camera's stored answer or a lost person's hold, so nothing keeps the muted kind past
    the mute's end."""
    if report is None or not muted:
        return report
    hits = []
    for hit in report.hits:
        if hit.zone_id not in muted:
            hits.append(hit)
            continue
        scale = muted[hit.zone_id]
        if scale is not None:
            hits.append(replace(hit, kind="warning", speed_scale=float(scale)))
    return replace(report, hits=tuple(hits))


def _worse(new: ZoneHit, old: ZoneHit) -> bool:
    if new.lost != old.lost:
        return new.lost
    if old.distance_m is None:
        return False
    return new.distance_m is None or new.distance_m < old.distance_m


# read-only request settings shared by every query (FCL copies them per call)
_DREQ = fcl.DistanceRequest()


def _check(prep: PreparedCell, camera_id: str, boxes_px: np.ndarray,
           tool_pose: geo.ToolPose | None, tool_speed_mps: float | None,
           band_px: tuple[float, float] = (0.0, 0.0),
           tool_state: ToolState | None = None,
           placed: occ.Placement | None = None) -> ZoneReport:
    cell = prep.cell
    tool_pose = pose_in_cell(prep, tool_pose)  # tracker frame -> cell (zone file tracker_frame)
    if camera_id not in cell.cameras:
        raise ConfigError(f"{cell.label}: unknown camera '{camera_id}' "
                          f"(cameras: {', '.join(sorted(cell.cameras))})")
    boxes = np.asarray(boxes_px, dtype=np.float64).reshape(-1, 4)
    if not np.all(np.isfinite(boxes)):
        raise InputError(f"camera '{camera_id}': non-finite person box coordinates")
    n = len(boxes)
    hits: list[ZoneHit] = []
    lo, hi = float(band_px[0]), float(max(band_px))
    place = (placed if placed is not None else placement(prep, camera_id, boxes, (lo, hi))) \
        if n else None
    img = prep.image_zones.get(camera_id)
    if img is not None and n:
        if place is not None:
            feet = (place.feet_u_px, place.feet_top_px, place.feet_bottom_px)
        else:
            u = (boxes[:, 0] + boxes[:, 2]) * 0.5
            top = np.maximum(boxes[:, 3] - hi, boxes[:, 1] + 1.0)
            feet = (u, top, np.maximum(boxes[:, 3] - lo, top))
        inside = img.inside(boxes, feet)
        cols, rows = np.nonzero((inside & img.alert_cols).T)
        hits.extend(ZoneHit(img.ids[c], img.kinds[c], int(i), img.scales[c], None)
                    for c, i in zip(cols.tolist(), rows.tolist(), strict=True))

    if place is not None and prep.volumes:
        hits.extend(_volume_hits(prep, place))
    if place is not None and prep.moving:  # zones that follow the tool (monitor/zones/moving.py)
        hits.extend(moving_hits(prep, place, tool_state))

    def measure() -> float | None:
        if place is None or not len(place.located):
            return None
        centres, located, slack, tall = _sample_ranges(prep, place)
        return max(_tool_separation(prep, tool_pose, centres, located,
                                    np.ones(len(centres), dtype=bool), tall) - slack, 0.0)

    sep = evaluate_separation(prep, tool_pose, tool_speed_mps, measure)
    return ZoneReport(
        hits=tuple(hits),
        masked=(),
        tool_separation_m=sep.separation_m,
        required_separation_m=sep.required_m,
        separation_speed_scale=sep.speed_scale,
        config_hash=cell.config_hash,
    )


def placement(prep: PreparedCell, camera_id: str, boxes_px: np.ndarray,
              band_px: tuple[float, float] = (0.0, 0.0)) -> occ.Placement | None:
    """The floor ranges the zone check tests for these boxes of ``camera_id`` (None without a
    calibration): the one placement, so that what a replay draws is what was checked."""
    model = prep.cell.camera_models.get(camera_id)
    if model is None:
        return None
    cam = prep.cell.cameras[camera_id]
    boxes = np.asarray(boxes_px, dtype=np.float64).reshape(-1, 4)
    return occ.place_persons(boxes, model, cam.width, cam.height,
                             band_px=(float(band_px[0]), float(max(band_px))),
                             height_range_m=prep.height_range_m,
                             occluder_columns=prep.occluder_columns.get(camera_id),
                             camera_centre=prep.camera_centres.get(camera_id),
                             floors=prep.floors,
                             edge_columns=prep.reference_edges.get(camera_id))


def _volume_hits(prep: PreparedCell, place: occ.Placement) -> list[ZoneHit]:
    """Protective and warning volumes that the swept person cylinder of each person touches."""
    r, h = prep.person.zone_radius_m, prep.person.height_m
    out: list[ZoneHit] = []
    lo_xy = np.minimum(place.near_m, place.far_m)
    hi_xy = np.maximum(place.near_m, place.far_m)
    z0, z1 = stand_span(place, h)
    near = _aabb_all(prep, lo_xy, hi_xy, r, z0, z1) & place.located[:, None] & prep.volume_alert
    shapes: dict[int, list[fcl.CollisionObject]] = {}
    ks, rows = np.nonzero(near.T)
    for k, i in zip(ks.tolist(), rows.tolist(), strict=True):
        v = prep.volumes[k]
        objs = shapes.get(i)
        if objs is None:
            objs = shapes[i] = swept_person(prep, place.near_m[i], place.far_m[i],
                                             float(z0[i]), float(z1[i]))
        if overlaps(objs, v, place.near_m[i], place.far_m[i], r, float(z1[i] - z0[i]),
                     float(z0[i])):
            out.append(ZoneHit(v.id, v.kind, i, v.speed_scale, 0.0))
    lost = np.flatnonzero(~place.located)
    # cannot be placed on the floor: inside every protective and warning volume (fail safe)
    out.extend(ZoneHit(v.id, v.kind, int(i), v.speed_scale, None)
               for v in prep.volumes if v.kind in ("protective", "warning") for i in lost)
    return out


def _sample_ranges(prep: PreparedCell, place: occ.Placement, step_m: float = 0.1
                   ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Person centres along every range, at most ``step_m`` apart, their located flags, the
    slack (half a step) to take off a distance so that it stays a lower bound, and each
    centre's cylinder height (the person height, more where floor regions raise or lower the
    possible surfaces: the cylinder then spans all of them)."""
    centres, located, tall = [], [], []
    ranged = False
    z0, z1 = stand_span(place, prep.person.height_m)
    for i in range(len(place.located)):
        a, b = place.near_m[i], place.far_m[i]
        length = float(np.hypot(*(b - a))) if place.located[i] else 0.0
        k = max(1, math.ceil(length / step_m))
        ranged |= length > 1e-4
        t = np.linspace(0.0, 1.0, k + 1)[:, None]
        pts = a + t * (b - a)
        centres.append(np.c_[pts, np.full(len(pts), (z0[i] + z1[i]) / 2)])
        located.append(np.full(len(pts), bool(place.located[i])))
        tall.append(np.full(len(pts), z1[i] - z0[i]))
    return (np.concatenate(centres), np.concatenate(located), step_m / 2 if ranged else 0.0,
            np.concatenate(tall))


def _tool_separation(prep: PreparedCell, pose: geo.ToolPose, centres: np.ndarray,
                     located: np.ndarray, active: np.ndarray,
                     heights: np.ndarray | None = None) -> float:
    """Smallest distance (m) from an active person's nominal cylinder to the tool; 0.0 when one
    of them cannot be placed (fail safe). ``heights``: each cylinder's height (the person
    height by default), centred on its centre."""
    if np.any(active & ~located):
        return 0.0
    tool = tool_object(prep, pose)
    # lower bound per person from the tool's bounding sphere; FCL runs nearest first and stops
    # once no remaining person can beat the best distance found
    m = geo.tool_transform(pose, prep.tool.offset) @ prep.tool.local
    c = m[:3, :3] @ prep.tool.bound_centre + m[:3, 3]
    idx = np.flatnonzero(active)
    dxy = np.maximum(np.hypot(centres[idx, 0] - c[0], centres[idx, 1] - c[1])
                     - prep.person.radius_m, 0.0)
    h = prep.person.height_m
    tall = np.full(len(centres), h) if heights is None else np.asarray(heights, float)
    top = centres[idx, 2] + tall[idx] / 2
    bottom = centres[idx, 2] - tall[idx] / 2
    dz = np.maximum(np.maximum(c[2] - top, bottom - c[2]), 0.0)
    bound = np.hypot(dxy, dz) - prep.tool.bound_radius
    best = math.inf
    for j in np.argsort(bound).tolist():
        if bound[j] >= best:
            break
        k = idx[j]
        cyl = prep.body_cylinder if tall[k] == h else fcl.Cylinder(prep.person.radius_m, tall[k])
        body = fcl.CollisionObject(cyl, fcl.Transform(centres[k]))
        best = min(best, max(float(fcl.distance(body, tool, _DREQ, fcl.DistanceResult())), 0.0))
    return best


def volume_distances(cell: Cell | PreparedCell, camera_id: str, boxes_px: np.ndarray
                     ) -> tuple[tuple[str, ...], np.ndarray]:
    """Distance (metres) from each person's zone cylinder (radius + Z_d) to each enabled
    protective or warning volume: (zone ids, (N, V) array), 0.0 on overlap, NaN for a person
    that cannot be placed (or a camera without calibration). For diagnosis and displays; the
    per-frame decision uses ``check_persons`` (cheaper: overlap only)."""
    prep = cell if isinstance(cell, PreparedCell) else cell.prepared
    if camera_id not in prep.cell.cameras:
        raise ConfigError(f"{prep.cell.label}: unknown camera '{camera_id}'")
    vols = [v for v in prep.volumes if v.kind != "mask"]
    boxes = np.asarray(boxes_px, dtype=np.float64).reshape(-1, 4)
    out = np.full((len(boxes), len(vols)), np.nan)
    model = prep.cell.camera_models.get(camera_id)
    if model is None or not len(boxes) or not vols:
        return tuple(v.id for v in vols), out
    bottom = np.stack([(boxes[:, 0] + boxes[:, 2]) * 0.5, boxes[:, 3]], axis=1)
    floor, located = model.pixel_to_floor(bottom)
    h, r = prep.person.height_m, prep.person.zone_radius_m
    for i in np.flatnonzero(located).tolist():
        centre = np.array([floor[i, 0], floor[i, 1], h / 2])
        obj = fcl.CollisionObject(prep.zone_cylinder, fcl.Transform(centre))
        for k, v in enumerate(vols):
            if overlaps([obj], v, floor[i], floor[i], r, h):
                out[i, k] = 0.0
            else:
                out[i, k] = min(float(fcl.distance(obj, p, _DREQ, fcl.DistanceResult()))
                                for p in v.parts)
    return tuple(v.id for v in vols), out


def _aabb_all(prep: PreparedCell, lo_xy: np.ndarray, hi_xy: np.ndarray, r: float,
              z0: np.ndarray | None = None, z1: np.ndarray | None = None) -> np.ndarray:
    """(N, V) bool: a person range's bounding box overlaps the zone's (broad phase); the
    persons span ``z0`` .. ``z1`` (floor to person height by default)."""
    lo, hi = prep.volume_lo[None], prep.volume_hi[None]
    n = len(lo_xy)
    z0 = np.zeros(n) if z0 is None else z0
    z1 = np.full(n, prep.person.height_m) if z1 is None else z1
    return (np.all(hi_xy[:, None, :] + r >= lo[..., :2], axis=2)
            & np.all(lo_xy[:, None, :] - r <= hi[..., :2], axis=2)
            & (z1[:, None] >= lo[..., 2]) & (hi[..., 2] >= z0[:, None]))


