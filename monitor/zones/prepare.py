"""Geometry of a cell built once for the per-frame queries (FCL objects, polygon edges)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import fcl
import numpy as np

from monitor import geometry as geo
from monitor.geometry.edges import horizontal_edges
from monitor.geometry.floors import FloorRegion
from monitor.geometry.occlusion import (
    OccluderColumns,
    PolygonSegments,
    camera_centre_m,
    occluder_outline_px,
    segments_hit_polygons,
)
from monitor.zones.moving_check import prepare_moving
from monitor.zones.schema import (
    CameraSpec,
    PolygonZone,
    ToolBox,
    ToolCylinder,
    ToolSphere,
)
from monitor.zones.views import CellData
from monitor.zones.volumes import Volume, occluder_corners_m, prepare_volume, zone_scale

# --------------------------------------------------------------------------------------------
# Prepared geometry for the per-frame query


@dataclass(frozen=True, eq=False)
class _ImageZones:
    """Enabled image zones of one camera, stacked for one vectorised pass per frame."""

    ids: tuple[str, ...]
    kinds: tuple[str, ...]
    scales: tuple[float, ...]
    anchors: tuple[str, ...]
    point_cols: np.ndarray  # zones decided by one anchor point
    point_edges: geo.PolygonEdges
    point_segments: PolygonSegments  # the same polygons, for feet ranges
    uses_centre: np.ndarray  # per point zone: anchor is the box centre
    area_cols: np.ndarray  # zones decided by overlap area
    area_min: np.ndarray  # per area zone: share needed (0 for any-overlap: > 0 pixels)
    integrals: np.ndarray  # (A, H+1, W+1) int32 summed-area tables of the area zones
    mask_cols: np.ndarray  # (Z,) bool
    alert_cols: np.ndarray  # (Z,) bool: protective or warning
    width: int
    height: int

    def inside(self, boxes: np.ndarray,
               feet_px: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """(N, Z) bool: box anchored in zone under each zone's anchor rule.

        ``feet_px`` = (u, top, bottom): the image rows the feet may be on (see
        ``monitor.geometry.occlusion.Placement``); a bottom-centre zone then counts the box when any
        point of that vertical segment is inside. Without it the box's bottom edge is used.
        """
        n = len(boxes)
        out = np.zeros((n, len(self.ids)), dtype=bool)
        if len(self.point_cols):
            pts = np.empty((n, 2))
            pts[:, 0] = (boxes[:, 0] + boxes[:, 2]) * 0.5
            pts[:, 1] = boxes[:, 3]
            if feet_px is None:
                res = self.point_edges.contains(pts)
            else:
                res = segments_hit_polygons(*feet_px, self.point_segments)
            if self.uses_centre.any():
                pts[:, 1] = (boxes[:, 1] + boxes[:, 3]) * 0.5
                res = np.where(self.uses_centre, self.point_edges.contains(pts), res)
            out[:, self.point_cols] = res
        if len(self.area_cols):
            lim = np.array([self.width, self.height, self.width, self.height])
            edges = np.empty((n, 4))
            edges[:, :2] = np.floor(boxes[:, :2])
            edges[:, 2:] = np.ceil(boxes[:, 2:])
            x1, y1, x2, y2 = np.clip(edges, 0, lim).astype(np.intp).T
            box_area = (x2 - x1) * (y2 - y1)
            t = self.integrals
            covered = t[:, y2, x2] - t[:, y1, x2] - t[:, y2, x1] + t[:, y1, x1]  # (A, N)
            need = np.maximum(self.area_min[:, None] * box_area[None], 1e-9)
            out[:, self.area_cols] = ((covered >= need) & (box_area > 0)).T
        return out


@dataclass(frozen=True, eq=False)
class _Tool:
    geometry: fcl.CollisionGeometry
    local: np.ndarray  # 4x4 geometry placement in the tool frame
    offset: np.ndarray  # 4x4 tool frame in the tracker frame
    bound_centre: np.ndarray  # bounding sphere of the geometry, in the geometry's frame
    bound_radius: float


@dataclass(frozen=True, eq=False)
class PreparedCell:
    """Everything the per-frame query needs, built once from a Cell (FCL objects, stacked
    polygon edges, summed-area tables). Read-only after construction."""

    cell: CellData
    image_zones: Mapping[str, _ImageZones]
    volumes: tuple[Volume, ...]
    volume_lo: np.ndarray  # (V, 3)
    volume_hi: np.ndarray
    volume_alert: np.ndarray  # (V,) bool: protective or warning (not mask)
    tool: _Tool | None
    person: geo.PersonModel
    separation: geo.SeparationParams
    zone_cylinder: fcl.Cylinder  # person widened by Z_d, for zone checks
    body_cylinder: fcl.Cylinder  # nominal person, for the tool distance
    axis_cylinder: fcl.Cylinder  # 1 mm person axis, for mask volumes
    occluders: tuple[Volume, ...] = ()  # fixtures that can hide a person
    # per camera: image outlines (convex hulls, raw pixels) of the occluders it sees
    occluder_outlines: Mapping[str, tuple[np.ndarray, ...]] = field(default_factory=dict)
    height_range_m: tuple[float, float] = (1.0, 2.0)
    occluder_columns: Mapping[str, OccluderColumns | None] = field(default_factory=dict)
    camera_centres: Mapping[str, np.ndarray | None] = field(default_factory=dict)
    floors: tuple[FloorRegion, ...] = ()  # raised or sunken floor regions (platforms, pits)
    moving: tuple[Any, ...] = ()  # zones that follow the tool (moving_check.MovingZone)
    # per camera: the commissioning reference's long horizontal edges (fixture tops, declared
    # or not: a box ending on one may have its feet hidden); empty without a reference
    reference_edges: Mapping[str, OccluderColumns] = field(default_factory=dict)


def prepare_cell(cell: CellData) -> PreparedCell:
    """Build the per-frame geometry of a cell (use ``cell.prepared`` to build it once)."""
    image: dict[str, _ImageZones] = {}
    for cam_id, cam in cell.cameras.items():
        zs = [z for z in cell.zones if isinstance(z, PolygonZone) and z.enabled
              and z.camera == cam_id and z.kind != "watch"]
        if zs:
            image[cam_id] = _prepare_image_zones(zs, cam)
    volumes = tuple(prepare_volume(z, cell) for z in cell.zones
                    if z.is_volume and z.enabled and z.kind not in ("watch", "occluder")
                    and getattr(z, "follow", None) is None)  # following zones: moving_check
    occ_zones = cell.spec.occluder_zones()  # the declared ones and the robot base, always
    occluders = tuple(prepare_volume(z, cell) for z in occ_zones)
    floors = tuple(FloorRegion.of(f.id, f.points_m, f.height_m) for f in cell.spec.floors)
    outlines: dict[str, tuple[np.ndarray, ...]] = {}
    for cam_id, model in cell.camera_models.items():
        hulls = [occluder_outline_px(occluder_corners_m(z, cell), model) for z in occ_zones]
        # a platform's sides hide the feet of a person behind it (and a pit's, of one in it)
        hulls += [occluder_outline_px(floor_corners_m(f), model) for f in floors]
        outlines[cam_id] = tuple(h for h in hulls if h is not None)
    columns = {cid: OccluderColumns.build(o, cell.cameras[cid].width, cell.cameras[cid].height)
               for cid, o in outlines.items()}
    centres = {cid: camera_centre_m(m) for cid, m in cell.camera_models.items()}
    p, s = cell.spec.person, cell.spec.separation
    person = geo.PersonModel(p.radius_m, p.height_m, p.position_uncertainty_m)
    return PreparedCell(
        cell=cell,
        image_zones=image,
        volumes=volumes,
        volume_lo=np.array([v.lo for v in volumes]).reshape(-1, 3),
        volume_hi=np.array([v.hi for v in volumes]).reshape(-1, 3),
        volume_alert=np.array([v.kind != "mask" for v in volumes], dtype=bool),
        tool=_prepare_tool(cell),
        person=person,
        separation=geo.SeparationParams(
            s.person_speed_mps, s.reaction_time_s, s.deceleration_mps2, s.intrusion_distance_m,
            s.robot_uncertainty_m, s.robot_speed_default_mps),
        zone_cylinder=fcl.Cylinder(person.zone_radius_m, person.height_m),
        body_cylinder=fcl.Cylinder(person.radius_m, person.height_m),
        axis_cylinder=fcl.Cylinder(0.001, person.height_m),
        occluders=occluders,
        occluder_outlines=outlines,
        height_range_m=tuple(p.height_range_m),
        occluder_columns=columns,
        camera_centres=centres,
        floors=floors,
        moving=prepare_moving(cell),
    )


def with_references(prep: PreparedCell, references: Mapping[str, np.ndarray | None]
                    ) -> PreparedCell:
    """``prep`` with the horizontal edges of each camera's commissioning reference (BGR, any
    size with the camera's aspect: resized to the camera's) for the hidden-feet test
    (``monitor.geometry.edges``). Cameras without a reference keep none."""
    edges: dict[str, OccluderColumns] = dict(prep.reference_edges)
    for cid, image in references.items():
        cam = prep.cell.cameras.get(cid)
        if image is None or cam is None:
            continue
        img = np.asarray(image)
        if (img.shape[1], img.shape[0]) != (cam.width, cam.height):
            img = cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
        edges[cid] = OccluderColumns.of_mask(horizontal_edges(img))
    return replace(prep, reference_edges=edges)


def floor_corners_m(region: FloorRegion) -> np.ndarray:
    """Corners (M, 3) of the solid between a floor region and the cell floor."""
    p = region.points_m
    return np.r_[np.c_[p, np.zeros(len(p))], np.c_[p, np.full(len(p), region.height_m)]]


def _prepare_image_zones(zs: list[PolygonZone], cam: CameraSpec) -> _ImageZones:
    point = [k for k, z in enumerate(zs) if z.anchor in ("bottom-centre", "centre")]
    area = [k for k, z in enumerate(zs) if z.anchor in ("any-overlap", "share")]
    integrals = np.zeros((len(area), cam.height + 1, cam.width + 1), dtype=np.int32)
    for a, k in enumerate(area):
        mask = np.zeros((cam.height, cam.width), dtype=np.uint8)
        # pixel (r, c) covers [c, c+1) x [r, r+1); fillPoly treats integer points as pixel
        # centres, hence the half-pixel shift (4 fractional bits)
        pts = np.round((np.array(zs[k].points_px) - 0.5) * 16).astype(np.int32)
        cv2.fillPoly(mask, [pts], 1, lineType=cv2.LINE_8, shift=4)
        integrals[a] = cv2.integral(mask, sdepth=cv2.CV_32S)
    return _ImageZones(
        ids=tuple(z.id for z in zs),
        kinds=tuple(z.kind for z in zs),
        scales=tuple(zone_scale(z) for z in zs),
        anchors=tuple(z.anchor for z in zs),
        point_cols=np.array(point, dtype=np.intp),
        point_edges=geo.PolygonEdges.build([np.array(zs[k].points_px) for k in point]),
        point_segments=PolygonSegments.build([np.array(zs[k].points_px) for k in point]),
        uses_centre=np.array([zs[k].anchor == "centre" for k in point], dtype=bool),
        area_cols=np.array(area, dtype=np.intp),
        area_min=np.array([zs[k].min_share or 0.0 for k in area], dtype=float),
        integrals=integrals,
        mask_cols=np.array([z.kind == "mask" for z in zs], dtype=bool),
        alert_cols=np.array([z.kind in ("protective", "warning") for z in zs], dtype=bool),
        width=cam.width,
        height=cam.height,
    )


def _prepare_tool(cell: CellData) -> _Tool | None:
    t = cell.spec.tool
    if t is None:
        return None
    offset = t.offset.tool_in_tracker()
    local = np.eye(4)
    centre = np.zeros(3)
    if isinstance(t, ToolCylinder):
        geom: fcl.CollisionGeometry = fcl.Cylinder(t.radius_m, t.length_m)
        local[2, 3] = t.length_m / 2  # fcl cylinders are centred; ours starts at the origin
        radius = math.hypot(t.radius_m, t.length_m / 2)
    elif isinstance(t, ToolBox):
        geom = fcl.Box(*t.size_m)
        local[2, 3] = t.size_m[2] / 2
        radius = float(np.linalg.norm(t.size_m)) / 2
    elif isinstance(t, ToolSphere):
        geom = fcl.Sphere(t.radius_m)
        radius = t.radius_m
    else:
        verts, faces = cell.meshes["tool"]
        model = fcl.BVHModel()
        model.beginModel(len(verts), len(faces))
        model.addSubModel(verts, faces)
        model.endModel()
        geom = model
        centre = (verts.min(axis=0) + verts.max(axis=0)) / 2
        radius = float(np.linalg.norm(verts - centre, axis=1).max())
    return _Tool(geom, local, offset, centre, radius)


def tool_object(prep: PreparedCell, pose: geo.ToolPose) -> fcl.CollisionObject | None:
    """The tool's collision object placed at ``pose`` (cell frame), or None without a tool."""
    if prep.tool is None:
        return None
    m = geo.tool_transform(pose, prep.tool.offset) @ prep.tool.local
    return fcl.CollisionObject(prep.tool.geometry, fcl.Transform(m[:3, :3], m[:3, 3]))


