"""The zone file schema (YAML, ``version: 1``): pydantic models with unknown keys refused."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from monitor import geometry as geo

SCHEMA_VERSION = 1
KINDS = ("protective", "warning", "mask", "watch", "occluder")
ANCHORS = ("bottom-centre", "centre", "any-overlap", "share")
VOLUME_SHAPES = ("extrude", "box", "cylinder", "mesh")
_ID = r"^[A-Za-z0-9][A-Za-z0-9_.-]*$"

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]


class _Strict(BaseModel):
    """Unknown keys refused; strict types: booleans must be true/false (``'no'``, ``'off'``,
    ``0`` are refused), numbers must be numbers (``'1.5'`` is refused), no NaN/inf. YAML lists
    are turned into tuples before validation (``files._as_tuples``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)


# --------------------------------------------------------------------------------------------
# Schema


class PinholeCalibration(_Strict):
    """Intrinsics K, OpenCV distortion and extrinsics with ``x_cam = R @ x_cell + t``."""

    type: Literal["pinhole"]
    camera_matrix: Mat3
    distortion: tuple[float, ...] = ()
    rotation: Mat3
    translation_m: Vec3


class HomographyCalibration(_Strict):
    """Image-to-floor point pairs ``[u_px, v_px, x_m, y_m]``; K and distortion, when given,
    undistort the pixels first."""

    type: Literal["homography"]
    pairs: tuple[tuple[float, float, float, float], ...]
    camera_matrix: Mat3 | None = None
    distortion: tuple[float, ...] = ()


Calibration = Annotated[PinholeCalibration | HomographyCalibration, Field(discriminator="type")]


class CameraSpec(_Strict):
    id: str = Field(pattern=_ID)
    width: int = Field(gt=0, le=32768)
    height: int = Field(gt=0, le=32768)
    calibration: Calibration | None = None
    # the reference image of the health checks (monitor reference capture), relative to the
    # zone file; it wins over monitor.toml's [[camera]] reference (monitor/health/references.py)
    reference: str | None = Field(default=None, min_length=1)


class MuteSpec(_Strict):
    """Who may mute a zone, for how long, and what it is while muted (docs/muting.md).

    ``max_s``: the longest mute one request may ask for. ``operators``: the operators (names
    of the monitor's operators file) allowed to mute this zone. ``as``: what a muted zone is
    checked as: ``warning`` (a person inside SLOWs at ``speed_scale``; the default) or
    ``none`` (not checked at all). ``speed_scale``: the SLOW scale of a muted zone checked as a
    warning zone; None: the slowest warning zone scale of the file (0.1 without one)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True,
                              serialize_by_alias=True)

    max_s: float = Field(gt=0.0, le=3600.0)
    operators: tuple[str, ...] = Field(min_length=1, max_length=100)
    as_: Literal["warning", "none"] = Field(default="warning", alias="as")
    speed_scale: float | None = Field(default=None, ge=0.0, lt=1.0)


class _ZoneBase(_Strict):
    id: str = Field(pattern=_ID)
    name: str = ""
    kind: Literal["protective", "warning", "mask", "watch", "occluder"]
    enabled: bool = True
    speed_scale: float | None = Field(default=None, ge=0.0, lt=1.0)
    # the explicit opt-in for a protective zone partly seen by no camera (zones validate and
    # monitor run refuse it otherwise; monitor/zones/coverage.py); None: not given (= false)
    unobserved_ok: bool | None = None
    # muting (docs/muting.md): a zone may be muted only when it says ``mute:``; ``unmutable:
    # true`` says it never may (a protective zone without ``mute:`` is unmutable anyway)
    mute: MuteSpec | None = None
    unmutable: bool | None = None

    @property
    def is_volume(self) -> bool:
        return False


class PolygonZone(_ZoneBase):
    """Image polygon of one camera, pixels at the camera's full resolution."""

    shape: Literal["polygon"]
    camera: str
    points_px: tuple[Vec2, ...]
    anchor: Literal["bottom-centre", "centre", "any-overlap", "share"] = "bottom-centre"
    min_share: float | None = Field(default=None, gt=0.0, le=1.0)


class FollowBox(_Strict):
    """A box in the cell frame (see ``BoxZone``)."""

    shape: Literal["box"]
    min_m: Vec3
    max_m: Vec3
    yaw_deg: float = 0.0


class FollowCylinder(_Strict):
    """A vertical cylinder in the cell frame (see ``CylinderZone``)."""

    shape: Literal["cylinder"]
    center_m: Vec2
    radius_m: float = Field(gt=0.0)
    z_min_m: float
    z_max_m: float


class FollowExtrude(_Strict):
    """An extruded floor polygon in the cell frame (see ``ExtrudeZone``)."""

    shape: Literal["extrude"]
    points_m: tuple[Vec2, ...]
    z_min_m: float
    z_max_m: float


MaxVolume = Annotated[FollowBox | FollowCylinder | FollowExtrude, Field(discriminator="shape")]


class FollowSpec(_Strict):
    """A volume zone that follows the tool (monitor/zones/moving.py, docs/moving-zones.md):
    its shape is given in the ``tool`` frame (or ``flange``: the frame the tool calibration's
    ``given_as: tracker_in_tool`` offset places) and moved with each fresh pose;
    ``grow_with_speed`` inflates it by S_p at the measured tool speed, at most
    ``max_growth_m``; ``max_volume`` (cell frame) is the zone whenever the pose is missing or
    older than ``policy.pose_timeout``: it must contain every place the zone can reach."""

    frame: Literal["tool", "flange"]
    grow_with_speed: bool = False
    max_growth_m: float | None = Field(default=None, gt=0.0, le=10.0)
    max_volume: MaxVolume


class _VolumeBase(_ZoneBase):
    # None: a cell-frame volume; else the zone follows the tool (monitor/zones/moving.py)
    follow: FollowSpec | None = None

    @property
    def is_volume(self) -> bool:
        return True


class ExtrudeZone(_VolumeBase):
    """Floor polygon (metres) extruded from ``z_min_m`` to ``z_max_m``."""

    shape: Literal["extrude"]
    points_m: tuple[Vec2, ...]
    z_min_m: float
    z_max_m: float


class BoxZone(_VolumeBase):
    """Box between two corners (metres), optionally turned by ``yaw_deg`` about its vertical."""

    shape: Literal["box"]
    min_m: Vec3
    max_m: Vec3
    yaw_deg: float = 0.0


class CylinderZone(_VolumeBase):
    """Vertical cylinder: floor centre, radius, z range (metres)."""

    shape: Literal["cylinder"]
    center_m: Vec2
    radius_m: float = Field(gt=0.0)
    z_min_m: float
    z_max_m: float


class MeshZone(_VolumeBase):
    """Closed mesh file (STL/OBJ/PLY), path relative to the zone file, cell frame; ``scale``
    converts its units to metres (0.001 for millimetres)."""

    shape: Literal["mesh"]
    file: str
    scale: float = Field(default=1.0, gt=0.0)


ZoneSpec = Annotated[
    PolygonZone | ExtrudeZone | BoxZone | CylinderZone | MeshZone, Field(discriminator="shape")
]


# a 1.55 m adult crouching (0.58 of the standing height): the smallest posture protected
CROUCHING_HEIGHT_M = 0.9
# the share of a person (top down, or from one side) the detector needs in view, until measured
# (the synthetic model's measured value, docs/occlusion.md "The visible fraction")
VISIBLE_FRACTION = 0.4


class PersonSpec(_Strict):
    """Person cylinder; ``position_uncertainty_m`` (Z_d) widens it for zone checks."""

    radius_m: float = Field(default=0.3, gt=0.0, le=2.0)
    height_m: float = Field(default=1.9, gt=0.0, le=3.0)
    position_uncertainty_m: float = Field(default=0.1, ge=0.0, le=2.0)
    # heights a person's head may be at (crouching .. tall): a box whose feet may be hidden is
    # placed from its top over this whole range (monitor/geometry/occlusion.py)
    height_range_m: tuple[float, float] = (1.0, 2.0)
    # the smallest posture the monitor must protect, as its head height (m): a person
    # crouching. Floor counts as seen by a camera only where ``visible_fraction`` of such a
    # person is in view (monitor/zones/visibility.py); None: CROUCHING_HEIGHT_M
    crouching_height_m: float | None = Field(default=None, gt=0.0, le=3.0)
    # the share of a person the detector needs in view to find them (measured beside the
    # operating envelope, ``monitor model envelope``; the service uses the larger of the two);
    # None: VISIBLE_FRACTION
    visible_fraction: float | None = Field(default=None, gt=0.0, le=1.0)

    @property
    def smallest_height_m(self) -> float:
        """Head height of the smallest posture to protect: crouching, or the shortest
        standing person when that is lower."""
        crouch = CROUCHING_HEIGHT_M if self.crouching_height_m is None \
            else self.crouching_height_m
        return float(min(crouch, self.height_range_m[0]))

    @property
    def needed_fraction(self) -> float:
        """The visible share of a person the detector needs (the zone file's or the default)."""
        return VISIBLE_FRACTION if self.visible_fraction is None else float(self.visible_fraction)


class SeparationSpec(_Strict):
    """ISO/TS 15066 speed and separation parameters (see geometry.SeparationParams and
    docs/separation.md).

    ``reaction_time_s`` (T_r) defaults to the sum of the default monitor configuration's
    delays (0.8 s, ``geometry.reaction_time_s``); ``monitor run`` uses the larger of it and the
    value computed from its own configuration. ``intrusion_distance_m`` (C) defaults to the
    ISO 13855 whole-body value 0.85 m (detection capability > 40 mm: a person detector).
    ``programmed_speed_mps`` is the robot's programmed tool speed: the command's speed scale is
    v_max(separation) / programmed speed, so RUN only where v_max allows all of it.
    """

    person_speed_mps: float = Field(default=1.6, ge=0.0, le=5.0)
    reaction_time_s: float = Field(default=geo.DEFAULT_REACTION_TIME_S, ge=0.0, le=5.0)
    deceleration_mps2: float = Field(default=2.0, gt=0.0, le=100.0)
    intrusion_distance_m: float = Field(default=geo.WHOLE_BODY_INTRUSION_M, ge=0.0, le=2.0)
    robot_uncertainty_m: float = Field(default=0.02, ge=0.0, le=1.0)
    robot_speed_default_mps: float = Field(default=1.0, ge=0.0, le=10.0)
    programmed_speed_mps: float = Field(default=1.0, gt=0.0, le=10.0)


class ToolOffset(_Strict):
    """Fixed mounting transform between the tracker body and the tool: translation
    (millimetres, as the tracker calibration gives it) and roll/pitch/yaw in degrees about fixed
    x, y, z. ``given_as`` says which way round the numbers are: ``tool_in_tracker`` (the tool
    frame expressed in the tracker frame, applied as ``pose @ offset``) or ``tracker_in_tool``
    (the tracker's mounting on the tool/flange, applied as ``pose @ inverse(offset)``)."""

    translation_mm: Vec3 = (0.0, 0.0, 0.0)
    rpy_deg: Vec3 = (0.0, 0.0, 0.0)
    given_as: Literal["tool_in_tracker", "tracker_in_tool"] = "tool_in_tracker"

    def tool_in_tracker(self) -> np.ndarray:
        """4x4 transform of the tool frame in the tracker frame (metres)."""
        m = geo.rigid(geo.rpy_to_matrix(*self.rpy_deg), np.array(self.translation_mm) / 1000.0)
        return np.linalg.inv(m) if self.given_as == "tracker_in_tool" else m


class _ToolBase(_Strict):
    offset: ToolOffset = ToolOffset()


class ToolCylinder(_ToolBase):
    """Cylinder along the tool's +z axis, from the tool origin to ``length_m``."""

    shape: Literal["cylinder"]
    radius_m: float = Field(gt=0.0, le=5.0)
    length_m: float = Field(gt=0.0, le=10.0)


class ToolBox(_ToolBase):
    """Box of ``size_m``, centred on the tool's z axis, from the tool origin along +z."""

    shape: Literal["box"]
    size_m: Vec3


class ToolSphere(_ToolBase):
    """Sphere centred on the tool origin."""

    shape: Literal["sphere"]
    radius_m: float = Field(gt=0.0, le=5.0)


class ToolMesh(_ToolBase):
    """Mesh file in the tool frame (path relative to the zone file); ``scale`` to metres."""

    shape: Literal["mesh"]
    file: str
    scale: float = Field(default=1.0, gt=0.0)


ToolSpec = Annotated[ToolCylinder | ToolBox | ToolSphere | ToolMesh, Field(discriminator="shape")]


class TrackerFrame(_Strict):
    """The tracker's reference frame in the cell: the OTUS tracker reports poses relative to
    where it was last reset, not in the cell. ``translation_m`` and ``rpy_deg`` (about fixed x,
    y, z) place that frame in the cell frame (cell_T_reference); a tool pose in the cell is
    ``tracker_frame @ tracker pose @ tool offset``. ``monitor zones calibrate-tool`` measures
    it. Without it the tracker frame is taken to be the cell frame."""

    translation_m: Vec3 = (0.0, 0.0, 0.0)
    rpy_deg: Vec3 = (0.0, 0.0, 0.0)

    def cell_from_tracker(self) -> np.ndarray:
        return geo.rigid(geo.rpy_to_matrix(*self.rpy_deg), self.translation_m)


class FloorSpec(_Strict):
    """A raised or sunken floor region where persons can stand: a horizontal surface at
    ``height_m`` above the cell floor over the floor polygon ``points_m`` (a platform, a
    mezzanine, a pit's floor: negative). Placement puts a person's feet on it where their
    sight line meets it inside the polygon, besides the cell floor (docs/occlusion.md)."""

    id: str = Field(pattern=_ID)
    name: str = ""
    points_m: tuple[Vec2, ...] = Field(min_length=3, max_length=1000)
    height_m: float = Field(ge=-10.0, le=20.0)


class RobotBaseSpec(_Strict):
    """The robot's base (pedestal, riser, controller cabinet beside it): a vertical cylinder on
    the floor that contains it. It is always an occluder: a person behind it may have their legs
    hidden, so a box cut at its top edge is placed from the head (monitor/geometry/occlusion.py).
    Without
    ``robot_base`` in the file the default (radius 0.5 m, 1.0 m high, at the cell origin, which
    is the robot base by the cell frame's definition) applies: declare yours when it is larger.
    """

    center_m: Vec2 = (0.0, 0.0)
    radius_m: float = Field(default=0.5, gt=0.0, le=5.0)
    height_m: float = Field(default=1.0, gt=0.0, le=5.0)

    def as_zone(self) -> CylinderZone:
        return CylinderZone(id=ROBOT_BASE_ID, name="robot base", kind="occluder",
                            shape="cylinder", center_m=self.center_m, radius_m=self.radius_m,
                            z_min_m=0.0, z_max_m=self.height_m)


ROBOT_BASE_ID = "robot_base"  # the id of the robot base's occluder (not a zone of the file)


class ZoneSetSpec(_Strict):
    """A zone set (a monitoring case): the protective and warning zones that apply while the
    robot program has selected it (docs/cases.md). Zones that no set names apply always.
    ``speed_scale`` caps the speed of the set's warning zones while it applies."""

    id: str = Field(pattern=_ID)
    name: str = ""
    zones: tuple[str, ...] = Field(min_length=1, max_length=1000)
    speed_scale: float | None = Field(default=None, ge=0.0, lt=1.0)


class CellSpec(_Strict):
    """The whole zone file."""

    version: Literal[1]
    name: str = ""
    description: str = ""
    person: PersonSpec = PersonSpec()
    separation: SeparationSpec = SeparationSpec()
    tool: ToolSpec | None = None
    tracker_frame: TrackerFrame | None = None
    cameras: tuple[CameraSpec, ...] = Field(min_length=1)
    zones: tuple[ZoneSpec, ...] = ()
    floors: tuple[FloorSpec, ...] = ()  # raised or sunken floor regions (platforms, pits)
    robot_base: RobotBaseSpec | None = None  # None: RobotBaseSpec() (the default base)
    # zone sets switched by a signed selection (docs/cases.md, monitor/cases/)
    sets: tuple[ZoneSetSpec, ...] = ()
    default_set: str | None = None  # the set in force at start (required with sets)
    transitions: tuple[tuple[str, str], ...] | None = None  # allowed [from, to]; None: any
    switch_over_s: float = Field(default=1.0, ge=0.0, le=60.0)  # both sets apply this long
    selector_ttl_s: float | None = Field(default=None, gt=0.0, le=3600.0)  # None: not watched

    def occluder_zones(self) -> tuple:
        """Every fixture that can hide a person: the enabled ``occluder`` volumes of the file
        and the robot base (always, declared or not)."""
        declared = tuple(z for z in self.zones
                         if z.is_volume and z.enabled and z.kind == "occluder")
        return (*declared, (self.robot_base or RobotBaseSpec()).as_zone())


