"""Zone file validation: one-line messages and small named cross-field checks."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from monitor import geometry as geo
from monitor.cases.muting import mute_faults
from monitor.geometry.distortion import distortion_fault
from monitor.zones.coverage import coverage_faults
from monitor.zones.floors import check_floors
from monitor.zones.moving import follow_faults, follows_tool, max_zone
from monitor.zones.schema import (
    BoxZone,
    CameraSpec,
    CellSpec,
    CylinderZone,
    ExtrudeZone,
    HomographyCalibration,
    MeshZone,
    PinholeCalibration,
    PolygonZone,
    ToolBox,
    ToolMesh,
)
from monitor.zones.set_checks import check_sets

# --------------------------------------------------------------------------------------------
# Error messages


def pydantic_message(exc: ValidationError, data: dict, index: int = 0,
                      errors: list | None = None) -> str:
    """One line for one pydantic error: where (zone id, camera id, section), field, fault.
    Pass ``errors`` (``exc.errors()``, built once) when formatting many: building the list is
    the costly part, and doing it per error made ``zones validate`` quadratic."""
    err = (errors if errors is not None else exc.errors())[index]
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
    elif typ in ("bool_type", "bool_parsing"):
        text = f"{field}: must be true or false (got {err.get('input')!r})"
    elif typ in ("float_type", "float_parsing", "int_type", "int_parsing"):
        text = f"{field}: must be a number, not {type(err.get('input')).__name__} " \
               f"{str(err.get('input'))[:40]!r}"
    else:
        got = f" (got {err['input']!r})" if isinstance(err.get("input"), int | float | str) \
            else ""
        text = f"{field}: {err['msg']}{got}" if field else err["msg"] + got
    return f"{where}: {text}" if where else text


def useful_errors(exc: ValidationError, data: Any) -> list:
    """``exc.errors()`` without the misleading ones: pydantic adds "at least one camera is
    needed" when the only camera is itself invalid (a typo in one of its keys); the camera's
    own error says what is wrong."""
    errs = exc.errors()
    cams = data.get("cameras") if isinstance(data, dict) else None
    if isinstance(cams, list | tuple) and len(cams) > 0:
        kept = [e for e in errs if not (e["type"] == "too_short" and tuple(e["loc"]) ==
                                        ("cameras",))]
        errs = kept or errs
    return errs


def _locate(loc: list, data: dict) -> tuple[str, list]:
    """Split a pydantic location into 'zone 'x'' / 'camera 'y'' / section and the field path,
    dropping the union tags pydantic inserts."""
    if len(loc) >= 2 and loc[0] in ("zones", "cameras", "floors") and isinstance(loc[1], int):
        items = data.get(loc[0]) or []
        item = items[loc[1]] if loc[1] < len(items) and isinstance(items[loc[1]], dict) else {}
        noun = {"zones": "zone", "cameras": "camera", "floors": "floor"}[loc[0]]
        ident = item.get("id")
        where = f"{noun} '{ident}'" if isinstance(ident, str) else f"{noun} #{loc[1] + 1}"
        rest = loc[2:]
        if loc[0] == "zones" and rest and rest[0] == item.get("shape"):
            rest = rest[1:]
        if loc[0] == "zones" and rest[:2] == ["follow", "max_volume"] and len(rest) > 2:
            rest = [*rest[:2], *rest[3:]]  # the shape's union tag pydantic inserts
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
    if loc and loc[0] in ("person", "separation", "tracker_frame"):
        return str(loc[0]), loc[1:]
    return "", loc


# --------------------------------------------------------------------------------------------
# Cross-field checks: small named functions, each yields messages


def check_spec(spec: CellSpec, base: Path
                ) -> tuple[list[str], list[str], dict[str, geo.CameraModel],
                           dict[str, tuple[np.ndarray, np.ndarray]]]:
    errors: list[str] = []
    warnings: list[str] = []
    models: dict[str, geo.CameraModel] = {}
    meshes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    errors += _check_unique_ids(spec)
    lo, hi = spec.person.height_range_m
    if not 0.3 <= lo < hi <= 3.0:
        errors.append(f"person: height_range_m [{lo:g}, {hi:g}] must be increasing within "
                      "[0.3, 3.0] m")
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
        faults = list(_check_kind_fields(z)) + list(mute_faults(z))
        if isinstance(z, PolygonZone):
            faults += _check_image_zone(z, cams)
        else:
            faults += _check_volume_zone(z, base, meshes)
            if follows_tool(z):  # its max_volume is a cell volume of its own
                faults += [f"follow.max_volume: {f}"
                           for f in _check_volume_zone(max_zone(z), base, meshes)]
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
    if not any(z.enabled and z.kind == "protective" for z in spec.zones):
        warnings.append("no enabled protective zone: a person anywhere in the cell can never "
                        "cause a STOP ('monitor run' refuses this file unless its configuration "
                        "allows it explicitly)")
    for cam in spec.cameras:
        has_image = any(isinstance(z, PolygonZone) and z.camera == cam.id and z.enabled
                        and z.kind in ("protective", "warning") for z in spec.zones)
        has_volume = any(z.is_volume and z.enabled and z.kind in ("protective", "warning")
                         for z in spec.zones)
        if not has_image and not (has_volume and cam.calibration is not None):
            warnings.append(f"camera '{cam.id}': no enabled protective or warning zone applies "
                            "to it (uncalibrated cameras see image zones only)")
    errors += follow_faults(spec)
    errors += _check_horizon(spec, models)
    errors += check_floors(spec)
    errors += check_sets(spec)
    if not errors:  # every protective and warning zone watched, or flagged (coverage.py)
        unseen_errors, unseen_warnings = coverage_faults(spec, models, meshes)
        errors += unseen_errors
        warnings += unseen_warnings
    return errors, warnings, models, meshes


def _check_horizon(spec: CellSpec, models: Mapping[str, geo.CameraModel]) -> list[str]:
    """An enabled protective or warning image zone anchored at the feet marks floor pixels:
    a calibration whose horizon puts any of its corners on the side that never meets the floor
    is wrong for this camera (or the polygon is), and a person standing there could not be
    placed on the floor. Refused, naming the corner and the horizon row."""
    out = []
    for z in spec.zones:
        if not (isinstance(z, PolygonZone) and z.enabled and z.camera in models
                and z.kind in ("protective", "warning") and z.anchor == "bottom-centre"):
            continue
        model = models[z.camera]
        pts = np.asarray(z.points_px, float).reshape(-1, 2)
        _, ok = model.pixel_to_floor(pts)
        if not ok.all():
            u, v = pts[int(np.flatnonzero(~ok)[0])]
            row = model.horizon_row_px()
            where = f" (horizon at row {row:.0f})" if row is not None else ""
            out.append(f"zone '{z.id}': corner ({u:g}, {v:g}) lies beyond camera "
                       f"'{z.camera}''s horizon{where}: the calibration says it never sees "
                       "the floor there; check the calibration or the polygon")
    return out


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
    if z.kind == "occluder" and not z.is_volume:
        yield "an occluder is a cell volume (box, extrude, cylinder or mesh), not an image polygon"
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
        if not faults:
            faults += _fold_fault(k, cal.distortion, cam)
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
    if not faults and k is not None:
        faults += _fold_fault(k, cal.distortion, cam)
    if faults:
        return faults, None
    dist = np.array(cal.distortion) if cal.distortion else None
    probe = geo.CameraModel(cam.width, cam.height, k, dist, None, None, np.eye(3), 1.0)
    try:
        h = geo.fit_homography(probe.undistort_px(pairs[:, :2]), pairs[:, 2:])
    except geo.GeometryError as exc:
        return [str(exc)], None
    return [], geo.CameraModel.from_homography(cam.width, cam.height, h, pairs[:, :2], k, dist)


def _fold_fault(k: np.ndarray, distortion: Sequence[float], cam: CameraSpec) -> list[str]:
    """A lens model that folds over the image maps one pixel to two floor points."""
    fault = distortion_fault(k, np.array(distortion, dtype=float), cam.width, cam.height)
    return [] if fault is None else [fault]


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


