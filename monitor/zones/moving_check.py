"""The per-step check of zones that follow the tool: FCL parts built once in the zone's own
frame, placed at each fresh pose (or the maximum volume), and tested against the persons'
swept cylinders with the growth as a distance (monitor/zones/moving.py, docs/moving-zones.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import fcl
import numpy as np

from monitor import geometry as geo
from monitor.geometry import occlusion as occ
from monitor.geometry.shapes import prism_geometries
from monitor.types import ZoneHit
from monitor.zones.moving import ToolState, cell_from_zone, growth_m, max_zone, transform_points
from monitor.zones.schema import BoxZone, CylinderZone, ExtrudeZone
from monitor.zones.views import CellData, PreparedData
from monitor.zones.volumes import (
    FCL_DISTANCE_MARGIN_M,
    Volume,
    occluder_corners_m,
    overlaps,
    prepare_volume,
    stand_span,
    swept_person,
    zone_scale,
)

_DREQ = fcl.DistanceRequest()


@dataclass(frozen=True, eq=False)
class MovingZone:
    """A following zone prepared once: its FCL geometries with their placement in the zone's
    frame, the points whose hull holds it (for the broad phase), its mesh (zone frame) and its
    maximum volume (cell frame)."""

    zone: Any
    parts: tuple[tuple[fcl.CollisionGeometry, np.ndarray], ...]
    hull: np.ndarray  # (M, 3), zone frame
    mesh: tuple[np.ndarray, np.ndarray] | None
    maximum: Volume

    @property
    def id(self) -> str:
        return self.zone.id


def prepare_moving(cell: CellData) -> tuple[MovingZone, ...]:
    """Every enabled following zone of the cell."""
    out = []
    for z in cell.zones:
        if not (z.is_volume and z.enabled and getattr(z, "follow", None) is not None):
            continue
        mesh = None
        if isinstance(z, BoxZone):
            lo, hi = np.array(z.min_m, float), np.array(z.max_m, float)
            parts = [(fcl.Box(*(hi - lo)), geo.rigid(geo.rpy_to_matrix(0, 0, z.yaw_deg),
                                                     (lo + hi) / 2))]
        elif isinstance(z, CylinderZone):
            centre = (*z.center_m, (z.z_min_m + z.z_max_m) / 2)
            parts = [(fcl.Cylinder(z.radius_m, z.z_max_m - z.z_min_m),
                      geo.rigid(np.eye(3), centre))]
        elif isinstance(z, ExtrudeZone):
            parts = [(g, np.eye(4)) for g in prism_geometries(
                np.array(z.points_m, float), z.z_min_m, z.z_max_m)]
        else:
            mesh = cell.meshes[z.id]
            model = fcl.BVHModel()
            model.beginModel(len(mesh[0]), len(mesh[1]))
            model.addSubModel(mesh[0], mesh[1])
            model.endModel()
            parts = [(model, np.eye(4))]
        out.append(MovingZone(z, tuple(parts), occluder_corners_m(z, cell), mesh,
                              prepare_volume(max_zone(z), cell)))
    return tuple(out)


def place_zone(mz: MovingZone, m: np.ndarray) -> Volume:
    """The zone at cell-from-zone transform ``m`` as a cell-frame volume."""
    objs = []
    for geom, local in mz.parts:
        t = m @ local
        objs.append(fcl.CollisionObject(geom, fcl.Transform(t[:3, :3], t[:3, 3])))
    pts = transform_points(m, mz.hull)
    mesh = None if mz.mesh is None else (transform_points(m, mz.mesh[0]), mz.mesh[1])
    z = mz.zone
    return Volume(z.id, z.kind, zone_scale(z), tuple(objs), pts.min(axis=0), pts.max(axis=0), mesh)


def placed_zones(prep: PreparedData, tool: ToolState | None
                 ) -> list[tuple[Volume, float, bool]]:
    """Each following zone as it stands this step: (volume, growth m, at maximum size). A
    fresh pose places it (grown with the speed); otherwise it is its maximum volume."""
    out = []
    for mz in prep.moving:
        m = cell_from_zone(prep.cell.spec, tool.pose) if tool is not None and tool.fresh \
            else None
        if m is None:
            out.append((mz.maximum, 0.0, True))
        else:
            out.append((place_zone(mz, m), growth_m(mz.zone, prep.separation, tool.speed_mps),
                        False))
    return out


def moving_hits(prep: PreparedData, place: occ.Placement, tool: ToolState | None
                ) -> list[ZoneHit]:
    """The persons that touch a following zone this step: the person's swept zone cylinder
    within the zone's growth of it (overlap when it does not grow); a person who cannot be
    placed is in every following zone (fail safe)."""
    zones = placed_zones(prep, tool)
    if not zones:
        return []
    r = prep.person.zone_radius_m
    z0, z1 = stand_span(place, prep.person.height_m)
    lo_xy = np.minimum(place.near_m, place.far_m)
    hi_xy = np.maximum(place.near_m, place.far_m)
    out: list[ZoneHit] = []
    for i in range(len(place.located)):
        if not place.located[i]:
            out.extend(ZoneHit(v.id, v.kind, i, v.speed_scale, None) for v, _, _ in zones)
            continue
        objs = None
        for v, grow, _ in zones:
            lo, hi = v.lo - grow, v.hi + grow  # broad phase: the grown bounding boxes
            if np.any(hi_xy[i] + r < lo[:2]) or np.any(lo_xy[i] - r > hi[:2]) \
                    or z1[i] < lo[2] or hi[2] < z0[i]:
                continue
            if objs is None:
                objs = swept_person(prep, place.near_m[i], place.far_m[i], float(z0[i]),
                                     float(z1[i]))
            if overlaps(objs, v, place.near_m[i], place.far_m[i], r, float(z1[i] - z0[i]),
                         float(z0[i])) or (grow > 0 and _within(objs, v, grow)):
                out.append(ZoneHit(v.id, v.kind, i, v.speed_scale, 0.0))
    return out


def _within(objs: list[fcl.CollisionObject], v: Volume, grow: float) -> bool:
    """Some part of the person is at most ``grow`` from the volume (FCL's distance, taken
    as over-reporting by up to FCL_DISTANCE_MARGIN_M)."""
    for obj in objs:
        for part in v.parts:
            d = float(fcl.distance(obj, part, _DREQ, fcl.DistanceResult()))
            if d - FCL_DISTANCE_MARGIN_M <= grow:
                return True
    return False
