"""The per-frame zone query: which persons are in which zones, how far from the tool."""

from __future__ import annotations

import math

import fcl
import numpy as np

from monitor import geometry as geo
from monitor.errors import ConfigError
from monitor.types import ZoneHit, ZoneReport
from monitor.zones.files import Cell
from monitor.zones.prepare import PreparedCell, _Volume, tool_object
from monitor.zones.separation import evaluate_separation, pose_in_cell

# --------------------------------------------------------------------------------------------
# The per-frame query


def check_persons(cell: Cell | PreparedCell, camera_id: str, boxes_px: np.ndarray,
                  tool_pose: geo.ToolPose | None = None,
                  tool_speed_mps: float | None = None,
                  foot_uncertainty_px: float = 0.0) -> ZoneReport:
    """Which persons of one frame are in which zones, and how far the nearest is from the tool.

    ``boxes_px`` is (N, 4) x1, y1, x2, y2 in pixels of ``camera_id`` at full resolution.
    Persons anchored in a mask zone are listed in ``masked`` and ignored otherwise. Image zones
    use each zone's anchor rule; volume zones place the box's bottom-centre on the floor through
    the camera's calibration and test a vertical cylinder (person radius + Z_d, person height)
    with FCL: a hit has ``distance_m`` 0.0. A person whose bottom-centre does not meet the floor
    (at or above the horizon) cannot be placed; to fail safe it hits every protective and
    warning volume zone with ``distance_m`` None and counts as touching the tool.

    ``tool_separation_m`` is the smallest distance from a nominal person cylinder (radius, no
    Z_d) to the tool placed at ``tool_pose`` (None without pose, tool, calibration or persons).
    ``required_separation_m`` is S_p (ISO/TS 15066, including Z_d) for ``tool_speed_mps``, or for
    ``separation.robot_speed_default_mps`` when the speed is unknown; None without a tool pose.
    ``separation_speed_scale`` is min(1, v_max(separation) / programmed speed), 0 when the tool
    is already faster than v_max (``monitor.zones.separation``, docs/separation.md).
    ``foot_uncertainty_px``: how far above the box's bottom edge the feet may really be (a
    detector whose boxes err large, e.g. by one grid cell). The persons are then checked twice,
    as detected and with the bottom edge raised by this much, and the answers are merged towards
    danger: every hit of either, the smaller distance, masked only if masked in both. Without
    it a box that reaches too low would place the person nearer the camera than they are, and
    a STOP for someone entering from the camera's side would come late.
    Answers only: no timers, no state.
    """
    prep = cell if isinstance(cell, PreparedCell) else cell.prepared
    report = _check(prep, camera_id, boxes_px, tool_pose, tool_speed_mps)
    if foot_uncertainty_px <= 0 or len(boxes_px) == 0:
        return report
    raised = np.array(boxes_px, np.float64).reshape(-1, 4)
    raised[:, 3] = np.maximum(raised[:, 3] - foot_uncertainty_px, raised[:, 1] + 1.0)
    return merge_towards_danger(report, _check(prep, camera_id, raised, tool_pose,
                                               tool_speed_mps))


def merge_towards_danger(a: ZoneReport, b: ZoneReport) -> ZoneReport:
    """Two answers for the same persons (different assumptions) as one, the worse of both."""
    hits: dict[tuple[str, int], ZoneHit] = {}
    for hit in (*a.hits, *b.hits):
        key = (hit.zone_id, hit.person)
        old = hits.get(key)
        if old is None or (hit.distance_m is not None and old.distance_m is not None
                           and hit.distance_m < old.distance_m):
            hits[key] = hit
    seps = [s for s in (a.tool_separation_m, b.tool_separation_m) if s is not None]
    reqs = [s for s in (a.required_separation_m, b.required_separation_m) if s is not None]
    scales = [s for s in (a.separation_speed_scale, b.separation_speed_scale) if s is not None]
    return ZoneReport(hits=tuple(hits.values()),
                      masked=tuple(sorted(set(a.masked) & set(b.masked))),
                      tool_separation_m=min(seps) if seps else None,
                      required_separation_m=max(reqs) if reqs else None,
                      separation_speed_scale=min(scales) if scales else None,
                      config_hash=a.config_hash)


# read-only request settings shared by every query (FCL copies them per call)
_REQ = fcl.CollisionRequest()
_DREQ = fcl.DistanceRequest()


def _check(prep: PreparedCell, camera_id: str, boxes_px: np.ndarray,
           tool_pose: geo.ToolPose | None, tool_speed_mps: float | None) -> ZoneReport:
    cell = prep.cell
    tool_pose = pose_in_cell(prep, tool_pose)  # tracker frame -> cell (zone file tracker_frame)
    if camera_id not in cell.cameras:
        raise ConfigError(f"{cell.label}: unknown camera '{camera_id}' "
                          f"(cameras: {', '.join(sorted(cell.cameras))})")
    boxes = np.asarray(boxes_px, dtype=np.float64).reshape(-1, 4)
    n = len(boxes)
    masked = np.zeros(n, dtype=bool)
    hits: list[ZoneHit] = []
    img = prep.image_zones.get(camera_id)
    inside = img.inside(boxes) if img is not None and n else None
    if inside is not None and img.mask_cols.any():
        masked |= inside[:, img.mask_cols].any(axis=1)

    model = cell.camera_models.get(camera_id)
    locate = model is not None and n > 0 and (bool(prep.volumes) or tool_pose is not None)
    if locate:
        bottom = np.empty((n, 2))
        bottom[:, 0] = (boxes[:, 0] + boxes[:, 2]) * 0.5
        bottom[:, 1] = boxes[:, 3]
        floor, located = model.pixel_to_floor(bottom)
        centres = np.empty((n, 3))
        centres[:, :2] = floor
        centres[:, 2] = prep.person.height_m / 2
    else:
        floor, located, centres = np.zeros((n, 2)), np.zeros(n, dtype=bool), np.zeros((n, 3))
    h = prep.person.height_m

    if locate and prep.volumes:
        # mask volumes first: a masked person takes part in nothing else
        for k, v in enumerate(prep.volumes):
            if v.kind == "mask":
                for i in np.flatnonzero(located & ~masked & _aabb(prep, k, floor, 0.001)):
                    obj = fcl.CollisionObject(prep.axis_cylinder, fcl.Transform(centres[i]))
                    if _overlaps(obj, v, centres[i], 0.001, h):
                        masked[i] = True

    if inside is not None:
        cols, rows = np.nonzero((inside & ~masked[:, None] & img.alert_cols).T)
        hits.extend(ZoneHit(img.ids[c], img.kinds[c], int(i), img.scales[c], None)
                    for c, i in zip(cols.tolist(), rows.tolist(), strict=True))

    active = ~masked
    if locate and prep.volumes:
        r = prep.person.zone_radius_m
        near = _aabb_all(prep, floor, r) & (located & active)[:, None] & prep.volume_alert
        objs: dict[int, fcl.CollisionObject] = {}
        ks, rows = np.nonzero(near.T)
        for k, i in zip(ks.tolist(), rows.tolist(), strict=True):
            v = prep.volumes[k]
            obj = objs.get(i)
            if obj is None:
                obj = objs[i] = fcl.CollisionObject(prep.zone_cylinder,
                                                    fcl.Transform(centres[i]))
            if _overlaps(obj, v, centres[i], r, h):
                hits.append(ZoneHit(v.id, v.kind, i, v.speed_scale, 0.0))
        lost = np.flatnonzero(~located & active)
        if len(lost):  # cannot be placed on the floor: inside every volume (fail safe)
            hits.extend(ZoneHit(v.id, v.kind, int(i), v.speed_scale, None)
                        for v in prep.volumes if v.kind != "mask" for i in lost)

    sep = evaluate_separation(
        prep, tool_pose, tool_speed_mps,
        lambda: _tool_separation(prep, tool_pose, centres, located, active)
        if model is not None and active.any() else None)
    return ZoneReport(
        hits=tuple(hits),
        masked=tuple(np.flatnonzero(masked).tolist()),
        tool_separation_m=sep.separation_m,
        required_separation_m=sep.required_m,
        separation_speed_scale=sep.speed_scale,
        config_hash=cell.config_hash,
    )


def _tool_separation(prep: PreparedCell, pose: geo.ToolPose, centres: np.ndarray,
                     located: np.ndarray, active: np.ndarray) -> float:
    """Smallest distance (m) from an active person's nominal cylinder to the tool; 0.0 when one
    of them cannot be placed (fail safe)."""
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
    dz = np.maximum(np.maximum(c[2] - prep.person.height_m, -c[2]), 0.0)
    bound = np.hypot(dxy, dz) - prep.tool.bound_radius
    best = math.inf
    for j in np.argsort(bound).tolist():
        if bound[j] >= best:
            break
        body = fcl.CollisionObject(prep.body_cylinder, fcl.Transform(centres[idx[j]]))
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
            if _overlaps(obj, v, centre, r, h):
                out[i, k] = 0.0
            else:
                out[i, k] = min(float(fcl.distance(obj, p, _DREQ, fcl.DistanceResult()))
                                for p in v.parts)
    return tuple(v.id for v in vols), out


def _aabb(prep: PreparedCell, k: int, floor: np.ndarray, r: float) -> np.ndarray:
    lo, hi = prep.volume_lo[k], prep.volume_hi[k]
    return ((floor[:, 0] + r >= lo[0]) & (floor[:, 0] - r <= hi[0])
            & (floor[:, 1] + r >= lo[1]) & (floor[:, 1] - r <= hi[1])
            & (prep.person.height_m >= lo[2]) & (hi[2] >= 0.0))


def _aabb_all(prep: PreparedCell, floor: np.ndarray, r: float) -> np.ndarray:
    """(N, V) bool: person bounding box overlaps the zone's bounding box (broad phase)."""
    lo, hi = prep.volume_lo[None], prep.volume_hi[None]
    f = floor[:, None, :]
    return (np.all(f + r >= lo[..., :2], axis=2) & np.all(f - r <= hi[..., :2], axis=2)
            & (prep.person.height_m >= lo[..., 2]) & (hi[..., 2] >= 0.0))


def _overlaps(obj: fcl.CollisionObject, v: _Volume, centre: np.ndarray, r: float,
              h: float) -> bool:
    for part in v.parts:
        if fcl.collide(obj, part, _REQ, fcl.CollisionResult()):
            return True
    if v.mesh is None:
        return False
    # FCL tests mesh surfaces only: with no surface contact the cylinder is wholly inside
    # or wholly outside the closed mesh (or the mesh is inside the cylinder)
    if geo.points_in_mesh(centre[None], *v.mesh)[0]:
        return True
    p = v.mesh[0][0]
    return bool(np.hypot(p[0] - centre[0], p[1] - centre[1]) <= r and 0.0 <= p[2] <= h)


