"""The report's details of a zone file, in numbers (pure: a loaded ``Cell`` in, JSON-able out):
each zone's geometry (corners, heights, radius), speed scale, mute rule and who may mute it;
the zone sets with who may select them; each camera's calibration and its residuals; the person
and separation parameters; the horizontal extent of each zone (what S_p is compared with).
"""

from __future__ import annotations

import math

import numpy as np

from monitor.zones import Cell


def _r(value: float) -> float:
    return round(float(value), 4)


def _box_corners(z) -> list[list[float]]:
    (x0, y0, _), (x1, y1, _) = z.min_m, z.max_m
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    a = math.radians(z.yaw_deg)
    out = []
    for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1)):
        dx, dy = x - cx, y - cy
        out.append([_r(cx + dx * math.cos(a) - dy * math.sin(a)),
                    _r(cy + dx * math.sin(a) + dy * math.cos(a))])
    return out


def geometry(z) -> dict:
    """A zone's shape in numbers (cell coordinates, metres; image zones in pixels)."""
    shape = getattr(z, "shape", "polygon")
    if shape == "box":
        return {"corners_m": _box_corners(z), "z_m": [_r(z.min_m[2]), _r(z.max_m[2])],
                "yaw_deg": _r(z.yaw_deg)}
    if shape == "cylinder":
        return {"centre_m": [_r(v) for v in z.center_m], "radius_m": _r(z.radius_m),
                "z_m": [_r(z.z_min_m), _r(z.z_max_m)]}
    if shape == "extrude":
        return {"corners_m": [[_r(x), _r(y)] for x, y in z.points_m],
                "z_m": [_r(z.z_min_m), _r(z.z_max_m)]}
    if shape == "mesh":
        return {"file": z.file, "scale": _r(z.scale)}
    return {"camera": z.camera, "points_px": [[_r(x), _r(y)] for x, y in z.points_px],
            "anchor": z.anchor}


def extent_m(z, cell: Cell | None = None) -> float | None:
    """The zone's largest horizontal extent (m); None for an image zone."""
    g = geometry(z)
    if "corners_m" in g:
        p = np.array(g["corners_m"], float)
        return _r(max(np.ptp(p[:, 0]), np.ptp(p[:, 1])))
    if "radius_m" in g:
        return _r(2 * g["radius_m"])
    if cell is not None and z.id in cell.meshes:
        v = cell.meshes[z.id][0]
        return _r(max(np.ptp(v[:, 0]), np.ptp(v[:, 1])))
    return None


def zones(cell: Cell) -> list[dict]:
    """Every zone with its geometry, speed scale, mute rule and extent."""
    out = []
    for z in cell.zones:
        mute = z.mute
        follow = getattr(z, "follow", None)
        out.append({
            "id": z.id, "name": z.name, "kind": z.kind, "shape": getattr(z, "shape", "polygon"),
            "enabled": bool(z.enabled), "camera": getattr(z, "camera", None),
            "geometry": geometry(z), "extent_m": extent_m(z, cell),
            "speed_scale": z.speed_scale, "unmutable": bool(z.unmutable),
            "mute": None if mute is None else {
                "max_s": mute.max_s, "operators": list(mute.operators), "as": mute.as_,
                "speed_scale": mute.speed_scale},
            "follows": None if follow is None else follow.frame})
    return out


def zone_sets(cell: Cell, selectors: list[str]) -> dict | None:
    """The zone sets (None: the file declares none) and who may select them."""
    spec = cell.spec
    if not spec.sets:
        return None
    return {"sets": [{"id": s.id, "name": s.name, "zones": list(s.zones),
                      "speed_scale": s.speed_scale} for s in spec.sets],
            "default": spec.default_set,
            "transitions": None if spec.transitions is None
            else [list(t) for t in spec.transitions],
            "switch_over_s": spec.switch_over_s, "selector_ttl_s": spec.selector_ttl_s,
            "selectors": selectors}


def calibrations(cell: Cell) -> list[dict]:
    """Each camera's calibration and, for a floor homography, the residuals of its point
    pairs on the floor (m) as the monitor maps them."""
    out = []
    for cam_id, cam in sorted(cell.cameras.items()):
        cal = cam.calibration
        row = {"camera": cam_id, "type": cal.type if cal is not None else None, "pairs": 0,
               "residual_max_m": None, "residual_mean_m": None}
        model = cell.camera_models.get(cam_id)
        if cal is not None and cal.type == "homography" and model is not None:
            pairs = np.array(cal.pairs, float).reshape(-1, 4)
            floor, _ = model.pixel_to_floor(pairs[:, :2])
            err = np.hypot(*(np.asarray(floor) - pairs[:, 2:]).T)
            row.update(pairs=len(pairs), residual_max_m=_r(err.max()),
                       residual_mean_m=_r(err.mean()))
        out.append(row)
    return out


def person_and_separation(cell: Cell) -> dict:
    return {"person": {k: (list(v) if isinstance(v, tuple) else v)
                       for k, v in cell.spec.person.model_dump().items()},
            "separation": cell.spec.separation.model_dump()}
