"""Zone files: schema, validation, atomic saving, and the per-frame zone query.

A zone file (YAML, ``version: 1``) describes one robot cell: its cameras (with an optional
calibration) and its zones. See ``zones/README.md`` for the format. Zone kinds:

* ``protective``: a person inside leads to STOP;
* ``warning``: a person inside leads to SLOW at ``speed_scale``;
* ``mask``: persons anchored inside are ignored (a poster, a mannequin);
* ``watch``: a region whose scene changes raise alerts (the health stage uses it).

A zone is an image polygon of one camera (pixels at that camera's full resolution) or a cell
volume (metres, z up, origin at the robot base on the floor): an extruded floor polygon, a box, a
vertical cylinder or a closed mesh file.

``load_cell`` validates everything before anything runs and raises ``ConfigError`` with one line
naming the file, the zone and the fault. ``check_persons`` answers, for one frame of one camera,
which persons are in which zones and how far they are from the tool; it keeps no state.
"""

from __future__ import annotations

import hashlib
import io
import itertools
import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Annotated, Any, Literal

import cv2
import fcl
import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from monitor import geometry as geo
from monitor.errors import ConfigError
from monitor.types import ZoneHit, ZoneReport

__all__ = [
    "Cell",
    "CellSpec",
    "PreparedCell",
    "check_persons",
    "draw_zones",
    "load_cell",
    "parse_cell",
    "prepare_cell",
    "save_cell",
    "volume_distances",
    "watch_regions",
    "write_cell_data",
]

SCHEMA_VERSION = 1
KINDS = ("protective", "warning", "mask", "watch")
ANCHORS = ("bottom-centre", "centre", "any-overlap", "share")
VOLUME_SHAPES = ("extrude", "box", "cylinder", "mesh")
_ID = r"^[A-Za-z0-9][A-Za-z0-9_.-]*$"

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


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


class _ZoneBase(_Strict):
    id: str = Field(pattern=_ID)
    name: str = ""
    kind: Literal["protective", "warning", "mask", "watch"]
    enabled: bool = True
    speed_scale: float | None = Field(default=None, ge=0.0, lt=1.0)

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


class _VolumeBase(_ZoneBase):
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


class PersonSpec(_Strict):
    """Person cylinder; ``position_uncertainty_m`` (Z_d) widens it for zone checks."""

    radius_m: float = Field(default=0.3, gt=0.0, le=2.0)
    height_m: float = Field(default=1.9, gt=0.0, le=3.0)
    position_uncertainty_m: float = Field(default=0.1, ge=0.0, le=2.0)


class SeparationSpec(_Strict):
    """ISO/TS 15066 speed and separation parameters (see geometry.SeparationParams)."""

    person_speed_mps: float = Field(default=1.6, ge=0.0, le=5.0)
    reaction_time_s: float = Field(default=0.1, ge=0.0, le=5.0)
    deceleration_mps2: float = Field(default=2.0, gt=0.0, le=100.0)
    intrusion_distance_m: float = Field(default=0.2, ge=0.0, le=2.0)
    robot_uncertainty_m: float = Field(default=0.02, ge=0.0, le=1.0)
    robot_speed_default_mps: float = Field(default=1.0, ge=0.0, le=10.0)


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


class CellSpec(_Strict):
    """The whole zone file."""

    version: Literal[1]
    name: str = ""
    description: str = ""
    person: PersonSpec = PersonSpec()
    separation: SeparationSpec = SeparationSpec()
    tool: ToolSpec | None = None
    cameras: tuple[CameraSpec, ...] = Field(min_length=1)
    zones: tuple[ZoneSpec, ...] = ()


# --------------------------------------------------------------------------------------------
# The validated cell


@dataclass(frozen=True, eq=False)
class Cell:
    """A validated zone file.

    ``cameras`` maps camera id to its spec; ``zones`` keeps the file order (disabled zones
    included); ``config_hash`` names the active zone set (see ``config_hash``);
    ``camera_models`` holds the calibrated cameras; ``warnings`` are doubts that do not stop.
    """

    spec: CellSpec
    path: Path | None
    cameras: Mapping[str, CameraSpec]
    zones: tuple[Any, ...]
    config_hash: str
    camera_models: Mapping[str, geo.CameraModel]
    meshes: Mapping[str, tuple[np.ndarray, np.ndarray]]  # zone id or "tool" -> (vertices, faces)
    warnings: tuple[str, ...] = ()

    def zone(self, zone_id: str) -> Any:
        for z in self.zones:
            if z.id == zone_id:
                return z
        raise ConfigError(f"{self.label}: no zone '{zone_id}'")

    @property
    def label(self) -> str:
        return str(self.path) if self.path is not None else "<cell>"

    @cached_property
    def prepared(self) -> PreparedCell:
        """Geometry built once for the per-frame queries (cached on this object)."""
        return prepare_cell(self)


def load_cell(path: str | os.PathLike) -> Cell:
    """Read and validate a zone file; raises ConfigError (one line) on any fault."""
    return parse_cell(read_cell_data(path), path)


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses a key given twice in one mapping (PyYAML keeps the last one
    silently, which could switch a zone's kind or enabled flag unnoticed)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


def _read_yaml(path: str | os.PathLike, load: Any, errors: tuple[type[Exception], ...]) -> Any:
    """Read a zone file and parse it with ``load(text)``; one-line ConfigError on any fault,
    with the line and column of a YAML syntax error."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: zone file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read zone file: {exc}") from None
    try:
        return load(text)
    except errors as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{p}{where}: YAML syntax error: {problem}") from None


def read_cell_data(path: str | os.PathLike) -> Any:
    """The YAML data of a zone file, unvalidated; ConfigError when unreadable or not YAML."""
    # a SafeLoader: no arbitrary objects; duplicate keys refused
    return _read_yaml(path, lambda text: yaml.load(text, Loader=_UniqueKeyLoader),
                      (yaml.YAMLError,))


def read_cell_document(path: str | os.PathLike) -> Any:
    """The zone file as an editable round-trip document (ruamel.yaml): dict- and list-like, and
    written back with its comments, key order and layout (``monitor zones`` edits use this)."""
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError as RtError

    # ruamel refuses duplicate keys too
    return _read_yaml(path, YAML(typ="rt").load, (RtError,))


def _flow_leaves(node: Any) -> Any:
    """New plain lists of numbers (points, matrices rows) in flow style: [x, y]."""
    from ruamel.yaml.comments import CommentedSeq

    if isinstance(node, dict):
        for key in list(node):
            node[key] = _flow_leaves(node[key])
        return node
    if isinstance(node, list):
        items = [_flow_leaves(v) for v in node]
        if isinstance(node, CommentedSeq):
            node[:] = items
            return node
        seq = CommentedSeq(items)
        if all(not isinstance(v, list | dict) for v in items):
            seq.fa.set_flow_style()
        return seq
    return node


def dump_cell_document(document: Any) -> str:
    from ruamel.yaml import YAML

    out = io.StringIO()
    yaml_rt = YAML(typ="rt")
    yaml_rt.width = 100
    yaml_rt.indent(mapping=2, sequence=4, offset=2)  # "key:\n  - item", as zones/ files are
    yaml_rt.dump(_flow_leaves(document), out)
    return out.getvalue()


def parse_cell(data: Any, path: str | os.PathLike | None = None) -> Cell:
    """Validate a zone file already parsed from YAML (a dict). Mesh paths are relative to the
    directory of ``path`` (the working directory without one)."""
    label = str(path) if path is not None else "<cell>"
    if not isinstance(data, dict):
        raise ConfigError(f"{label}: a zone file must be a YAML mapping with version, cameras, "
                          "zones")
    try:
        spec = CellSpec.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{label}: {_pydantic_message(exc, data)}") from None
    base = Path(path).parent if path is not None else Path.cwd()
    errors, warnings, models, meshes = _check_spec(spec, base)
    if errors:
        more = ""
        if len(errors) > 1:
            more = f" (and {len(errors) - 1} more; run 'monitor zones validate')"
        raise ConfigError(f"{label}: {errors[0]}{more}")
    return Cell(
        spec=spec,
        path=Path(path) if path is not None else None,
        cameras={c.id: c for c in spec.cameras},
        zones=tuple(spec.zones),
        config_hash=config_hash(spec, meshes_sha=_mesh_digests(spec, base)),
        camera_models=models,
        meshes=meshes,
        warnings=tuple(warnings),
    )


def cell_faults(data: Any, path: str | os.PathLike | None = None) -> tuple[list[str], list[str]]:
    """All errors and warnings of a zone file's data (for ``monitor zones validate``)."""
    if not isinstance(data, dict):
        return ["a zone file must be a YAML mapping with version, cameras, zones"], []
    try:
        spec = CellSpec.model_validate(data)
    except ValidationError as exc:
        return [_pydantic_message(exc, data, index=k) for k in range(len(exc.errors()))], []
    base = Path(path).parent if path is not None else Path.cwd()
    errors, warnings, _, _ = _check_spec(spec, base)
    return errors, warnings


def cell_to_data(cell_or_spec: Cell | CellSpec) -> dict:
    """Plain data (lists, dicts, numbers) of a cell, as it is written to YAML."""
    spec = cell_or_spec.spec if isinstance(cell_or_spec, Cell) else cell_or_spec
    return spec.model_dump(mode="json", exclude_none=True)


class _Dumper(yaml.SafeDumper):
    """Lists of numbers in flow style ([x, y]) so that polygons stay readable."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(not isinstance(v, list | dict) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def dump_cell_yaml(cell_or_spec: Cell | CellSpec) -> str:
    header = ("# workcell-monitor zone file (format: zones/README.md). Written by "
              "'monitor zones new'.\n")
    body = yaml.dump(cell_to_data(cell_or_spec), Dumper=_Dumper, sort_keys=False,
                     allow_unicode=True, width=100)
    return header + body


def save_cell(cell: Cell, path: str | os.PathLike, document: Any = None) -> None:
    """Write the cell atomically: a temp file in the same directory is renamed over ``path``;
    an existing file is first copied to ``path.bak``. With ``document`` (from
    :func:`read_cell_document`, already validated as ``cell``) the file keeps its comments."""
    target = Path(path)
    text = dump_cell_document(document) if document is not None else dump_cell_yaml(cell)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        if target.exists():
            shutil.copymode(target, tmp)
        else:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        if target.exists():
            bak_tmp = target.with_name(f".{target.name}.bak.tmp")
            shutil.copy2(target, bak_tmp)
            os.replace(bak_tmp, target.with_name(target.name + ".bak"))
        os.replace(tmp, target)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise ConfigError(f"{target}: cannot write zone file: {exc}") from None


def write_cell_data(data: Any, path: str | os.PathLike) -> Cell:
    """Validate zone-file data and, only when valid, save it atomically to ``path`` (the
    previous file is kept as ``path.bak``). On a fault nothing is written."""
    from ruamel.yaml.comments import CommentedMap

    cell = parse_cell(data, path)
    save_cell(cell, path, data if isinstance(data, CommentedMap) else None)
    return cell


def config_hash(spec: CellSpec, meshes_sha: Mapping[str, str] | None = None) -> str:
    """Stable, order-independent name of the active configuration.

    sha256 over canonical JSON of the cameras (sorted by id), the ENABLED zones (sorted by id,
    display names left out, mesh files by content hash), the person, separation and tool
    settings. Reordering the file, renaming a zone's display name or adding a disabled zone
    keeps the hash; any change that can alter a decision changes it.
    """
    meshes_sha = meshes_sha or {}
    zones = []
    for z in spec.zones:
        if not z.enabled:
            continue
        d = z.model_dump(mode="json", exclude={"name", "enabled"})
        if z.shape == "mesh":
            d["file_sha256"] = meshes_sha.get(z.id, "")
        zones.append(d)
    tool = None
    if spec.tool is not None:
        tool = spec.tool.model_dump(mode="json")
        if spec.tool.shape == "mesh":
            tool["file_sha256"] = meshes_sha.get("tool", "")
    payload = {
        "version": spec.version,
        "cameras": sorted((c.model_dump(mode="json") for c in spec.cameras),
                          key=lambda c: c["id"]),
        "zones": sorted(zones, key=lambda z: z["id"]),
        "person": spec.person.model_dump(mode="json"),
        "separation": spec.separation.model_dump(mode="json"),
        "tool": tool,
    }
    blob = json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _mesh_digests(spec: CellSpec, base: Path) -> dict[str, str]:
    out = {}
    for z in spec.zones:
        if z.shape == "mesh":
            out[z.id] = hashlib.sha256((base / z.file).read_bytes()).hexdigest()
    if spec.tool is not None and spec.tool.shape == "mesh":
        out["tool"] = hashlib.sha256((base / spec.tool.file).read_bytes()).hexdigest()
    return out


# --------------------------------------------------------------------------------------------
# Error messages


def _pydantic_message(exc: ValidationError, data: dict, index: int = 0) -> str:
    """One line for one pydantic error: where (zone id, camera id, section), field, fault."""
    err = exc.errors()[index]
    loc = list(err["loc"])
    where, rest = _locate(loc, data)
    field = ".".join(str(p) for p in rest)
    typ = err["type"]
    ctx = err.get("ctx") or {}
    if typ == "missing":
        text = f"missing field '{field}'"
    elif typ == "extra_forbidden":
        text = f"unknown field '{field}'"
    elif typ == "literal_error":
        name = rest[-1] if rest else "value"
        text = f"unknown {name} {err.get('input')!r} (expected {ctx.get('expected')})"
    elif typ == "union_tag_invalid":
        text = (f"unknown {ctx.get('discriminator', 'type').strip(chr(39))} "
                f"{ctx.get('tag')!r} (expected {ctx.get('expected_tags')})")
    elif typ == "union_tag_not_found":
        disc = str(ctx.get("discriminator", "type")).strip("'")
        text = f"missing field '{(field + '.') if field else ''}{disc}'"
    elif typ == "string_pattern_mismatch":
        text = f"{field}: {err.get('input')!r} is not a valid id (letters, digits, _ . -)"
    elif typ == "too_short" and field == "cameras":
        text = "cameras: at least one camera is needed"
    else:
        got = f" (got {err['input']!r})" if isinstance(err.get("input"), int | float | str) \
            else ""
        text = f"{field}: {err['msg']}{got}" if field else err["msg"] + got
    return f"{where}: {text}" if where else text


def _locate(loc: list, data: dict) -> tuple[str, list]:
    """Split a pydantic location into 'zone 'x'' / 'camera 'y'' / section and the field path,
    dropping the union tags pydantic inserts."""
    if len(loc) >= 2 and loc[0] in ("zones", "cameras") and isinstance(loc[1], int):
        items = data.get(loc[0]) or []
        item = items[loc[1]] if loc[1] < len(items) and isinstance(items[loc[1]], dict) else {}
        noun = "zone" if loc[0] == "zones" else "camera"
        ident = item.get("id")
        where = f"{noun} '{ident}'" if isinstance(ident, str) else f"{noun} #{loc[1] + 1}"
        rest = loc[2:]
        if loc[0] == "zones" and rest and rest[0] == item.get("shape"):
            rest = rest[1:]
        if loc[0] == "cameras" and len(rest) >= 2 and rest[0] == "calibration":
            cal = item.get("calibration")
            if isinstance(cal, dict) and rest[1] == cal.get("type"):
                rest = [rest[0], *rest[2:]]
        return where, rest
    if loc and loc[0] == "tool":
        tool = data.get("tool")
        rest = loc[1:]
        if isinstance(tool, dict) and rest and rest[0] == tool.get("shape"):
            rest = rest[1:]
        return "tool", rest
    if loc and loc[0] in ("person", "separation"):
        return str(loc[0]), loc[1:]
    return "", loc


# --------------------------------------------------------------------------------------------
# Cross-field checks: small named functions, each yields messages


def _check_spec(spec: CellSpec, base: Path
                ) -> tuple[list[str], list[str], dict[str, geo.CameraModel],
                           dict[str, tuple[np.ndarray, np.ndarray]]]:
    errors: list[str] = []
    warnings: list[str] = []
    models: dict[str, geo.CameraModel] = {}
    meshes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    errors += _check_unique_ids(spec)
    cams = {c.id: c for c in spec.cameras}
    for cam in spec.cameras:
        faults, model = _check_calibration(cam)
        errors += [f"camera '{cam.id}': calibration: {f}" for f in faults]
        if model is not None:
            models[cam.id] = model
            if isinstance(cam.calibration, HomographyCalibration):
                rms = _homography_rms(cam.calibration, model)
                if rms > 2.0:
                    warnings.append(f"camera '{cam.id}': calibration reprojection error "
                                    f"{rms:.2f} px RMS (> 2 px: check the point pairs)")
    calibrated = any(c.calibration is not None for c in spec.cameras)
    for z in spec.zones:
        faults = list(_check_kind_fields(z))
        if isinstance(z, PolygonZone):
            faults += _check_image_zone(z, cams)
        else:
            faults += _check_volume_zone(z, base, meshes)
            if not calibrated:
                faults.append("volume zone but no camera has a calibration: persons cannot be "
                              "placed in the cell (run 'monitor zones calibrate' first)")
        errors += [f"zone '{z.id}': {f}" for f in faults]
    if spec.tool is not None and isinstance(spec.tool, ToolMesh):
        fault, mesh = _load_mesh(base / spec.tool.file, spec.tool.scale, need_closed=False)
        if fault:
            errors.append(f"tool: {fault}")
        else:
            meshes["tool"] = mesh
    if isinstance(spec.tool, ToolBox) and min(spec.tool.size_m) <= 0:
        errors.append("tool: size_m must be positive on every axis")
    for cam in spec.cameras:
        has_image = any(isinstance(z, PolygonZone) and z.camera == cam.id and z.enabled
                        and z.kind in ("protective", "warning") for z in spec.zones)
        has_volume = any(z.is_volume and z.enabled and z.kind in ("protective", "warning")
                         for z in spec.zones)
        if not has_image and not (has_volume and cam.calibration is not None):
            warnings.append(f"camera '{cam.id}': no enabled protective or warning zone applies "
                            "to it (uncalibrated cameras see image zones only)")
    return errors, warnings, models, meshes


def _check_unique_ids(spec: CellSpec) -> list[str]:
    out = []
    seen: set[str] = set()
    for c in spec.cameras:
        if c.id in seen:
            out.append(f"camera '{c.id}': duplicate camera id")
        seen.add(c.id)
    seen = set()
    for z in spec.zones:
        if z.id in seen:
            out.append(f"zone '{z.id}': duplicate zone id")
        seen.add(z.id)
    return out


def _check_kind_fields(z: Any) -> Iterable[str]:
    if z.kind == "warning" and z.speed_scale is None:
        yield "warning zone needs speed_scale (allowed speed fraction, 0 <= s < 1)"
    if z.kind != "warning" and z.speed_scale is not None:
        yield f"speed_scale is only for warning zones, not {z.kind}"


def _check_image_zone(z: PolygonZone, cams: Mapping[str, CameraSpec]) -> list[str]:
    out = []
    cam = cams.get(z.camera)
    if cam is None:
        out.append(f"unknown camera '{z.camera}' (cameras: {', '.join(sorted(cams))})")
    fault = geo.polygon_fault(z.points_px)
    if fault:
        out.append(f"points_px: {fault}")
    if cam is not None:
        for k, (x, y) in enumerate(z.points_px):
            if not (0 <= x <= cam.width and 0 <= y <= cam.height):
                out.append(f"points_px: point {k + 1} ({x:g}, {y:g}) is outside the "
                           f"{cam.width}x{cam.height} image of camera '{cam.id}'")
                break
    if z.anchor == "share" and z.min_share is None:
        out.append("anchor 'share' needs min_share (fraction of the box area, 0 < x <= 1)")
    if z.anchor != "share" and z.min_share is not None:
        out.append(f"min_share is only for anchor 'share', not '{z.anchor}'")
    return out


def _check_z(z_min: float, z_max: float) -> list[str]:
    if not (math.isfinite(z_min) and math.isfinite(z_max)):
        return ["z_min_m and z_max_m must be finite"]
    return [] if z_min < z_max else [f"z_min >= z_max ({z_min:g} >= {z_max:g} m)"]


def _check_volume_zone(z: Any, base: Path,
                       meshes: dict[str, tuple[np.ndarray, np.ndarray]]) -> list[str]:
    if isinstance(z, ExtrudeZone):
        fault = geo.polygon_fault(z.points_m)
        return ([f"points_m: {fault}"] if fault else []) + _check_z(z.z_min_m, z.z_max_m)
    if isinstance(z, BoxZone):
        out = _check_z(z.min_m[2], z.max_m[2])
        for axis, lo, hi in zip("xy", z.min_m[:2], z.max_m[:2], strict=True):
            if not lo < hi:
                out.append(f"box min_m.{axis} >= max_m.{axis} ({lo:g} >= {hi:g} m)")
        return out
    if isinstance(z, CylinderZone):
        return _check_z(z.z_min_m, z.z_max_m)
    if isinstance(z, MeshZone):
        fault, mesh = _load_mesh(base / z.file, z.scale, need_closed=True)
        if fault:
            return [fault]
        meshes[z.id] = mesh
        return []
    return [f"unknown shape '{getattr(z, 'shape', '?')}'"]


def _load_mesh(path: Path, scale: float, need_closed: bool
               ) -> tuple[str | None, tuple[np.ndarray, np.ndarray]]:
    empty = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    if not path.is_file():
        return f"mesh file {path} not found", empty
    import trimesh  # slow to import (scipy): only when a cell uses a mesh

    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as exc:  # trimesh raises many types for bad files
        return f"mesh file {path} cannot be read: {type(exc).__name__}: {exc}", empty
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        return f"mesh file {path} has no triangles", empty
    if need_closed and not mesh.is_watertight:
        return f"mesh file {path} is not closed (not watertight): it encloses no volume", empty
    return None, (np.asarray(mesh.vertices, dtype=float) * scale,
                  np.asarray(mesh.faces, dtype=np.int64))


def _check_calibration(cam: CameraSpec) -> tuple[list[str], geo.CameraModel | None]:
    cal = cam.calibration
    if cal is None:
        return [], None
    if isinstance(cal, PinholeCalibration):
        k = np.array(cal.camera_matrix, dtype=float)
        faults = _check_k(k) + _check_distortion(cal.distortion)
        r = np.array(cal.rotation, dtype=float)
        if np.abs(r @ r.T - np.eye(3)).max() > 1e-4 or np.linalg.det(r) < 0:
            faults.append("rotation is not a rotation matrix (R R^T != I or det < 0)")
        if faults:
            return faults, None
        try:
            model = geo.CameraModel.pinhole(cam.width, cam.height, k,
                                            np.array(cal.distortion) if cal.distortion else None,
                                            r, np.array(cal.translation_m))
        except geo.GeometryError as exc:
            return [str(exc)], None
        return [], model
    faults = []
    if len(cal.pairs) < 4:
        return [f"needs at least 4 point pairs, got {len(cal.pairs)}"], None
    k = None
    if cal.camera_matrix is not None:
        k = np.array(cal.camera_matrix, dtype=float)
        faults += _check_k(k)
    faults += _check_distortion(cal.distortion)
    if cal.distortion and any(cal.distortion) and k is None:
        faults.append("distortion needs camera_matrix")
    pairs = np.array(cal.pairs, dtype=float)
    for n, (u, v) in enumerate(pairs[:, :2]):
        if not (0 <= u <= cam.width and 0 <= v <= cam.height):
            faults.append(f"pair {n + 1}: pixel ({u:g}, {v:g}) is outside the "
                          f"{cam.width}x{cam.height} image")
            break
    if faults:
        return faults, None
    dist = np.array(cal.distortion) if cal.distortion else None
    probe = geo.CameraModel(cam.width, cam.height, k, dist, None, None, np.eye(3), 1.0)
    try:
        h = geo.fit_homography(probe.undistort_px(pairs[:, :2]), pairs[:, 2:])
    except geo.GeometryError as exc:
        return [str(exc)], None
    return [], geo.CameraModel.from_homography(cam.width, cam.height, h, pairs[:, :2], k, dist)


def _check_k(k: np.ndarray) -> list[str]:
    if not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0 or k[1, 0] != 0 \
            or k[2, 0] != 0 or k[2, 1] != 0 or k[2, 2] != 1:
        return ["camera_matrix must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0"]
    return []


def _check_distortion(d: Sequence[float]) -> list[str]:
    if len(d) not in (0, 4, 5, 8, 12, 14):
        return [f"distortion needs 4, 5, 8, 12 or 14 OpenCV coefficients, got {len(d)}"]
    return []


def _homography_rms(cal: HomographyCalibration, model: geo.CameraModel) -> float:
    pairs = np.array(cal.pairs, dtype=float)
    err = geo.reprojection_errors_px(model.homography, model.undistort_px(pairs[:, :2]),
                                     pairs[:, 2:])
    return float(np.sqrt(np.mean(err**2)))


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
    point_edges: geo._PolygonEdges
    uses_centre: np.ndarray  # per point zone: anchor is the box centre
    area_cols: np.ndarray  # zones decided by overlap area
    area_min: np.ndarray  # per area zone: share needed (0 for any-overlap: > 0 pixels)
    integrals: np.ndarray  # (A, H+1, W+1) int32 summed-area tables of the area zones
    mask_cols: np.ndarray  # (Z,) bool
    alert_cols: np.ndarray  # (Z,) bool: protective or warning
    width: int
    height: int

    def inside(self, boxes: np.ndarray) -> np.ndarray:
        """(N, Z) bool: box anchored in zone under each zone's anchor rule."""
        n = len(boxes)
        out = np.zeros((n, len(self.ids)), dtype=bool)
        if len(self.point_cols):
            pts = np.empty((n, 2))
            pts[:, 0] = (boxes[:, 0] + boxes[:, 2]) * 0.5
            pts[:, 1] = boxes[:, 3]
            res = self.point_edges.contains(pts)
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
class _Volume:
    id: str
    kind: str
    speed_scale: float
    parts: tuple[fcl.CollisionObject, ...]
    lo: np.ndarray  # axis-aligned bounds, metres
    hi: np.ndarray
    mesh: tuple[np.ndarray, np.ndarray] | None  # closed mesh: containment needs a ray test


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

    cell: Cell
    image_zones: Mapping[str, _ImageZones]
    volumes: tuple[_Volume, ...]
    volume_lo: np.ndarray  # (V, 3)
    volume_hi: np.ndarray
    volume_alert: np.ndarray  # (V,) bool: protective or warning (not mask)
    tool: _Tool | None
    person: geo.PersonModel
    separation: geo.SeparationParams
    zone_cylinder: fcl.Cylinder  # person widened by Z_d, for zone checks
    body_cylinder: fcl.Cylinder  # nominal person, for the tool distance
    axis_cylinder: fcl.Cylinder  # 1 mm person axis, for mask volumes

    def check(self, camera_id: str, boxes_px: np.ndarray, tool_pose: geo.ToolPose | None = None,
              tool_speed_mps: float | None = None) -> ZoneReport:
        return _check(self, camera_id, boxes_px, tool_pose, tool_speed_mps)


def prepare_cell(cell: Cell) -> PreparedCell:
    """Build the per-frame geometry of a cell (use ``cell.prepared`` to build it once)."""
    image: dict[str, _ImageZones] = {}
    for cam_id, cam in cell.cameras.items():
        zs = [z for z in cell.zones if isinstance(z, PolygonZone) and z.enabled
              and z.camera == cam_id and z.kind != "watch"]
        if zs:
            image[cam_id] = _prepare_image_zones(zs, cam)
    volumes = tuple(_prepare_volume(z, cell) for z in cell.zones
                    if z.is_volume and z.enabled and z.kind != "watch")
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
    )


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
        scales=tuple(_scale(z) for z in zs),
        anchors=tuple(z.anchor for z in zs),
        point_cols=np.array(point, dtype=np.intp),
        point_edges=geo._PolygonEdges.build([np.array(zs[k].points_px) for k in point]),
        uses_centre=np.array([zs[k].anchor == "centre" for k in point], dtype=bool),
        area_cols=np.array(area, dtype=np.intp),
        area_min=np.array([zs[k].min_share or 0.0 for k in area], dtype=float),
        integrals=integrals,
        mask_cols=np.array([z.kind == "mask" for z in zs], dtype=bool),
        alert_cols=np.array([z.kind in ("protective", "warning") for z in zs], dtype=bool),
        width=cam.width,
        height=cam.height,
    )


def _scale(z: Any) -> float:
    return float(z.speed_scale) if z.kind == "warning" and z.speed_scale is not None else 0.0


def _prepare_volume(z: Any, cell: Cell) -> _Volume:
    mesh = None
    if isinstance(z, ExtrudeZone):
        pts = np.array(z.points_m, dtype=float)
        parts = geo.fcl_prism_parts(pts, z.z_min_m, z.z_max_m)
        lo = np.r_[pts.min(axis=0), z.z_min_m]
        hi = np.r_[pts.max(axis=0), z.z_max_m]
    elif isinstance(z, BoxZone):
        parts = [geo.fcl_box(z.min_m, z.max_m, z.yaw_deg)]
        corners = _box_corners(z)
        lo, hi = corners.min(axis=0), corners.max(axis=0)
    elif isinstance(z, CylinderZone):
        parts = [geo.fcl_vertical_cylinder(z.center_m, z.radius_m, z.z_min_m, z.z_max_m)]
        c = np.array(z.center_m)
        lo = np.r_[c - z.radius_m, z.z_min_m]
        hi = np.r_[c + z.radius_m, z.z_max_m]
    else:
        mesh = cell.meshes[z.id]
        parts = [geo.fcl_mesh(*mesh)]
        lo, hi = mesh[0].min(axis=0), mesh[0].max(axis=0)
    return _Volume(z.id, z.kind, _scale(z), tuple(parts), np.asarray(lo, float),
                   np.asarray(hi, float), mesh)


def _prepare_tool(cell: Cell) -> _Tool | None:
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
    return ZoneReport(hits=tuple(hits.values()),
                      masked=tuple(sorted(set(a.masked) & set(b.masked))),
                      tool_separation_m=min(seps) if seps else None,
                      required_separation_m=max(reqs) if reqs else None,
                      config_hash=a.config_hash)


# read-only request settings shared by every query (FCL copies them per call)
_REQ = fcl.CollisionRequest()
_DREQ = fcl.DistanceRequest()


def _check(prep: PreparedCell, camera_id: str, boxes_px: np.ndarray,
           tool_pose: geo.ToolPose | None, tool_speed_mps: float | None) -> ZoneReport:
    cell = prep.cell
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

    separation = None
    required = None
    if tool_pose is not None and prep.tool is not None:
        speed = prep.separation.robot_speed_default_mps if tool_speed_mps is None \
            else float(tool_speed_mps)
        required = geo.protective_separation_m(speed, prep.separation,
                                               prep.person.position_uncertainty_m)
        if model is not None and active.any():
            separation = _tool_separation(prep, tool_pose, centres, located, active)
    return ZoneReport(
        hits=tuple(hits),
        masked=tuple(np.flatnonzero(masked).tolist()),
        tool_separation_m=separation,
        required_separation_m=required,
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


# --------------------------------------------------------------------------------------------
# Outlines in an image: watch regions and drawing


def volume_outline_m(z: Any, cell: Cell, segments: int = 32) -> list[np.ndarray]:
    """Polylines (each (M, 3), metres) that draw a volume zone as a wireframe."""
    if isinstance(z, ExtrudeZone | CylinderZone):
        if isinstance(z, ExtrudeZone):
            base = np.array(z.points_m, dtype=float)
        else:
            a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
            base = np.c_[z.center_m[0] + z.radius_m * np.cos(a),
                         z.center_m[1] + z.radius_m * np.sin(a)]
        return _prism_lines(base, z.z_min_m, z.z_max_m, vertical=isinstance(z, ExtrudeZone))
    if isinstance(z, BoxZone):
        c = _box_corners(z)
        return _prism_lines(c[:4, :2], z.min_m[2], z.max_m[2])
    verts, faces = cell.meshes[z.id]
    edges = np.unique(np.sort(np.r_[faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]],
                              axis=1), axis=0)
    if len(edges) > 3000:  # a dense mesh: draw its bounding box instead
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        base = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        return _prism_lines(base, lo[2], hi[2])
    return [verts[e] for e in edges]


def _prism_lines(base: np.ndarray, z0: float, z1: float, vertical: bool = True
                 ) -> list[np.ndarray]:
    ring = np.r_[base, base[:1]]
    lines = [np.c_[ring, np.full(len(ring), z0)], np.c_[ring, np.full(len(ring), z1)]]
    step = 1 if vertical else max(1, len(base) // 4)
    lines += [np.array([[x, y, z0], [x, y, z1]]) for x, y in base[::step]]
    return lines


def _box_corners(z: BoxZone) -> np.ndarray:
    lo, hi = np.array(z.min_m), np.array(z.max_m)
    c = (lo + hi) / 2
    half = (hi - lo) / 2
    sx, sy = half[0], half[1]
    base = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]])
    rot = geo.rpy_to_matrix(0, 0, z.yaw_deg)[:2, :2]
    xy = base @ rot.T + c[:2]
    return np.r_[np.c_[xy, np.full(4, lo[2])], np.c_[xy, np.full(4, hi[2])]]


def _project_lines(model: geo.CameraModel, lines: list[np.ndarray], samples: int = 24
                   ) -> list[np.ndarray]:
    """Project 3-D polylines; each segment is sampled so that lens distortion bends it, and
    the parts behind the camera are dropped. Returns 2-D polylines in raw pixels."""
    out = []
    for line in lines:
        t = np.linspace(0, 1, samples)[:, None]
        pts = np.concatenate([a + t * (b - a) for a, b in itertools.pairwise(line)])
        px, front = model.project(pts)
        run: list[np.ndarray] = []
        for p, ok in zip(px, front, strict=True):
            if ok and np.all(np.isfinite(p)) and np.all(np.abs(p) < 1e6):
                run.append(p)
            elif run:
                if len(run) > 1:
                    out.append(np.array(run))
                run = []
        if len(run) > 1:
            out.append(np.array(run))
    return out


def _volume_region_px(z: Any, cell: Cell, model: geo.CameraModel, cam: CameraSpec
                      ) -> np.ndarray | None:
    """Image outline (convex hull) of a volume zone, clipped to the image; None if unseen."""
    lines = _project_lines(model, volume_outline_m(z, cell), samples=8)
    if not lines:
        return None
    pts = np.concatenate(lines).astype(np.float32)
    hull = cv2.convexHull(pts).reshape(-1, 2)
    clipped = geo.clip_polygon_to_rect(hull, cam.width, cam.height)
    if len(clipped) < 3 or abs(geo.polygon_signed_area(clipped)) < 1.0:
        return None
    return clipped


def watch_regions(cell: Cell, camera_id: str) -> list[tuple[str, np.ndarray]]:
    """Enabled ``watch`` zones seen by one camera: (zone id, polygon (K, 2) float32 pixels).

    Image zones are returned as drawn; volume zones as the convex hull of their projection
    through the camera's calibration, clipped to the image (homography-only cameras see the
    floor footprint only). Volume zones out of view, or cameras without calibration, give none.
    """
    cam = cell.cameras.get(camera_id)
    if cam is None:
        raise ConfigError(f"{cell.label}: unknown camera '{camera_id}'")
    model = cell.camera_models.get(camera_id)
    out = []
    for z in cell.zones:
        if z.kind != "watch" or not z.enabled:
            continue
        if isinstance(z, PolygonZone):
            if z.camera == camera_id:
                out.append((z.id, np.array(z.points_px, dtype=np.float32)))
        elif model is not None:
            region = _volume_region_px(z, cell, model, cam)
            if region is not None:
                out.append((z.id, region.astype(np.float32)))
    return out


COLOURS_BGR = {
    "protective": (40, 40, 230),
    "warning": (0, 170, 255),
    "mask": (170, 170, 170),
    "watch": (230, 160, 30),
}


def draw_zones(frame_bgr: np.ndarray, cell: Cell, camera_id: str,
               hit_zone_ids: Iterable[str] = ()) -> np.ndarray:
    """A copy of the frame with the camera's zones drawn and labelled.

    Image zones are filled (translucent) and outlined; volume zones are projected through the
    calibration as wireframes with a filled floor footprint. Zones in ``hit_zone_ids`` are drawn
    thicker and labelled HIT. A frame of another size than the camera is drawn scaled.
    """
    cam = cell.cameras.get(camera_id)
    if cam is None:
        raise ConfigError(f"{cell.label}: unknown camera '{camera_id}'")
    img = np.ascontiguousarray(frame_bgr).copy()
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    sx, sy = img.shape[1] / cam.width, img.shape[0] / cam.height
    scale = np.array([sx, sy])
    hit = set(hit_zone_ids)
    model = cell.camera_models.get(camera_id)
    fills = img.copy()
    outlines: list[tuple[list[np.ndarray], tuple[int, int, int], int, str]] = []
    # most important last, so that protective zones stay visible on top of warning areas
    order = {"watch": 0, "mask": 1, "warning": 2, "protective": 3}
    for z in sorted(cell.zones, key=lambda z: order[z.kind]):
        if not z.enabled:
            continue
        colour = COLOURS_BGR[z.kind]
        thick = 4 if z.id in hit else 2
        if isinstance(z, PolygonZone):
            if z.camera != camera_id:
                continue
            poly = np.array(z.points_px) * scale
            cv2.fillPoly(fills, [_i32(poly)], colour, lineType=cv2.LINE_AA, shift=4)
            outlines.append(([poly], colour, thick, z.id))
        elif model is not None:
            lines = [ln * scale for ln in _project_lines(model, volume_outline_m(z, cell))]
            if not lines:
                continue
            region = _volume_floor_px(z, cell, model)
            if region is not None:
                cv2.fillPoly(fills, [_i32(region * scale)], colour, lineType=cv2.LINE_AA,
                             shift=4)
            outlines.append((lines, colour, thick, z.id))
    cv2.addWeighted(fills, 0.35, img, 0.65, 0, dst=img)
    for polys, colour, thick, zid in outlines:
        closed = len(polys) == 1
        cv2.polylines(img, [_i32(p) for p in polys], closed, colour, thick, cv2.LINE_AA, 4)
        _label(img, polys, f"{zid}{' HIT' if zid in hit else ''}", colour)
    return img


def _volume_floor_px(z: Any, cell: Cell, model: geo.CameraModel) -> np.ndarray | None:
    """Projected footprint of a volume at its lowest z (for the translucent fill)."""
    lines = volume_outline_m(z, cell)
    if isinstance(z, MeshZone):
        return None
    bottom = _project_lines(model, lines[:1], samples=8)
    if len(bottom) != 1:
        return None
    return bottom[0]


def _i32(p: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(p) * 16).astype(np.int32)


def _label(img: np.ndarray, polys: list[np.ndarray], text: str, colour: tuple[int, int, int]
           ) -> None:
    pts = np.concatenate(polys)
    near_top = pts[pts[:, 1] <= pts[:, 1].min() + 1.0]
    top = near_top[int(np.argmin(near_top[:, 0]))]  # above the top-left-most outline point
    x = int(np.clip(top[0], 2, max(2, img.shape[1] - 8 * len(text))))
    y = int(np.clip(top[1] - 6, 14, img.shape[0] - 4))
    font = cv2.FONT_HERSHEY_SIMPLEX
    (w, th), _ = cv2.getTextSize(text, font, 0.5, 1)
    cv2.rectangle(img, (x - 2, y - th - 4), (x + w + 2, y + 4), (0, 0, 0), -1)
    cv2.putText(img, text, (x, y), font, 0.5, colour, 1, cv2.LINE_AA)
