"""``monitor zones``: create, edit, check and preview zone files.

Every write validates the whole file first (nothing is written when it fails), then replaces the
file atomically and keeps the previous version as FILE.bak.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from monitor import geometry as geo
from monitor import zones as zn
from monitor.cli import cases, zone_calibrate, zone_cameras, zone_mutes
from monitor.cli.tool_calibration import calibrate_tool, positive_number
from monitor.cli.zone_cameras import parse_size, write_new_zone_file
from monitor.cli.zone_files import (
    camera_for,
    document_defaults,
    numbers,
    plural,
    read_zone_data,
    write_zone_data,
)
from monitor.cli.zones_apply import register as register_apply
from monitor.errors import ConfigError, InputError
from monitor.zones.cameras import choose_camera, zone_file_hint


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "zones", help="create, edit, validate and preview zone files",
        description="Edit zone files (format: zones/README.md). Every write is validated first "
        "and atomic; the previous file is kept as FILE.bak.")
    sub = parser.add_subparsers(dest="zones_command", metavar="ACTION", required=True)

    p = sub.add_parser("new", help="create a zone file with one camera (more: zones camera "
                       "add)")
    p.add_argument("file", type=Path)
    p.add_argument("--camera", required=True, help="camera id, e.g. cam0")
    p.add_argument("--size", required=True, help="camera resolution WxH, e.g. 1280x720")
    p.add_argument("--name", default="", help="cell name")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.set_defaults(func=cmd_new)

    p = sub.add_parser("add", help="add a zone: an image polygon or a cell volume",
                       description="Add a zone. Image polygon: POINTS as 'x,y x,y ...' in pixels "
                       "with --camera. Volumes (metres): --box, --cylinder, --extrude + --z, "
                       "--mesh.")
    p.add_argument("file", type=Path)
    p.add_argument("id", help="zone id (letters, digits, _ . -)")
    p.add_argument("points", nargs="?", help="image polygon 'x,y x,y x,y ...' (pixels)")
    p.add_argument("--kind", required=True, choices=zn.KINDS, help="zone kind")
    _zone_options(p)
    p.add_argument("--disabled", action="store_true", help="add the zone disabled")
    p.set_defaults(func=cmd_add, late_positionals=late_points)

    p = sub.add_parser("edit", help="change fields or the geometry of a zone")
    p.add_argument("file", type=Path)
    p.add_argument("id")
    p.add_argument("--new-id", help="rename the zone id")
    p.add_argument("--kind", choices=zn.KINDS, help="zone kind")
    p.add_argument("--points", help="new image polygon 'x,y x,y ...' (pixels)")
    _zone_options(p)
    p.set_defaults(func=cmd_edit)

    p = sub.add_parser("remove", help="remove a zone")
    p.add_argument("file", type=Path)
    p.add_argument("id")
    p.set_defaults(func=cmd_remove)

    for action, flag in (("enable", True), ("disable", False)):
        p = sub.add_parser(action, help=f"{action} zones")
        p.add_argument("file", type=Path)
        p.add_argument("ids", nargs="+", metavar="ID")
        p.set_defaults(func=cmd_enable, enabled=flag)

    p = sub.add_parser("list", help="list the zones as a table")
    p.add_argument("file", type=Path)
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("show", help="show one zone")
    p.add_argument("file", type=Path)
    p.add_argument("id")
    p.set_defaults(func=cmd_show)

    p = sub.add_parser("validate", help="check a zone file; print every fault")
    p.add_argument("file", type=Path)
    p.add_argument("--config", type=Path, default=None,
                   help="a monitor.toml: also warn about what its [handover] peers cannot "
                        "take from this file (default: none)")
    p.set_defaults(func=cmd_validate)

    zone_calibrate.register(sub)

    p = sub.add_parser("preview", help="draw the zones over a camera frame")
    p.add_argument("file", type=Path)
    p.add_argument("--frame", required=True, type=Path, help="camera image (PNG, JPEG, ...)")
    p.add_argument("--out", required=True, type=Path, help="output PNG")
    p.add_argument("--camera", help="camera id (default: the file's only camera; required "
                   "when it has several)")
    p.add_argument("--hit", action="append", default=[], metavar="ID",
                   help="draw this zone as hit (repeatable)")
    p.add_argument("--tool-pose", type=tool_pose_arg, metavar="X,Y,Z,ROLL,PITCH,YAW",
                   help="draw the zones that follow the tool at this tracker pose (metres in "
                   "the tracker's frame, degrees about fixed x, y, z), not grown (default: "
                   "none, they are drawn at their max_volume, as a stale pose makes them)")
    p.set_defaults(func=cmd_preview)

    p = sub.add_parser("hash", help="print the config hash of the active zone set")
    p.add_argument("file", type=Path)
    p.set_defaults(func=cmd_hash)

    register_apply(sub)

    p = sub.add_parser(
        "calibrate-tool", help="measure the tracker's mounting and frame from robot poses",
        description="Closed-loop calibration of the tracked tool (docs/separation.md): from "
        "pairs of robot flange poses (cell frame, from the robot controller) and tracker poses "
        "(the tracker's own frame) it solves A X = Y B for the tracker's mounting on the flange "
        "(written as tool.offset, given_as tracker_in_tool) and the tracker's frame in the cell "
        "(written as tracker_frame), and prints the residual of every pose. CSV rows: flange "
        "x,y,z (m), qx,qy,qz,qw, then tracker x,y,z (m), qx,qy,qz,qw (quaternions x, y, z, w).")
    p.add_argument("file", type=Path)
    p.add_argument("--csv", type=Path, required=True,
                   help="CSV of pose pairs, 14 numbers a row (header optional)")
    p.add_argument("--tracker-noise-mm", type=positive_number, default=1.0,
                   help="expected tracker noise per axis, one standard deviation (mm; OTUS: "
                   "±1 mm precision)")
    p.add_argument("--tracker-noise-deg", type=positive_number, default=1.0,
                   help="expected tracker orientation noise per axis, one standard deviation "
                   "(degrees; OTUS: ±1 deg)")
    p.add_argument("--max-error-mm", type=positive_number, default=10.0,
                   help="refuse when the poses leave the mounting or the tracker frame this "
                   "uncertain under the tracker noise (mm; the OTUS accuracy is ±10 mm)")
    p.add_argument("--max-error-deg", type=positive_number, default=1.0,
                   help="the same for their rotations (degrees)")
    p.add_argument("--max-residual-mm", type=positive_number,
                   help="refuse to write when a pose's residual is larger (mm)")
    p.add_argument("--max-residual-deg", type=positive_number,
                   help="refuse to write when a pose's residual is larger (degrees)")
    p.add_argument("--dry-run", action="store_true", help="print the residuals, write nothing")
    p.set_defaults(func=cmd_calibrate_tool)

    for name, action in sub.choices.items():
        none_text = {"edit": "unchanged", "calibrate-tool": "what the tracker noise explains"}
        document_defaults(action, none_text.get(name, "not set"))

    zone_cameras.register(sub)

    cases.register_zone_sets(sub)
    zone_mutes.register(sub)


def _zone_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--name", help="display name")
    p.add_argument("--camera", help="camera id of an image polygon (default: the file's only "
                   "camera; required when it has several)")
    p.add_argument("--anchor", choices=zn.ANCHORS,
                   help="person anchor of an image polygon (default bottom-centre)")
    p.add_argument("--min-share", type=float, help="share of the box area for --anchor share")
    p.add_argument("--speed-scale", type=float, help="allowed speed fraction of a warning zone")
    p.add_argument("--box", metavar="X1,Y1,Z1,X2,Y2,Z2",
                   help="box between two corners (m); write --box=-1,... when the first number "
                   "is negative")
    p.add_argument("--yaw", type=float, help="box yaw about its vertical axis (degrees)")
    p.add_argument("--cylinder", metavar="X,Y,R,ZMIN,ZMAX",
                   help="vertical cylinder (m); --cylinder=-1,... when negative")
    p.add_argument("--extrude", metavar="'x,y x,y ...'",
                   help="floor polygon (m), with --z; --extrude='-1,-1 ...' when negative")
    p.add_argument("--z", metavar="ZMIN,ZMAX", help="height range of --extrude (m)")
    p.add_argument("--mesh", help="closed mesh file (STL/OBJ/PLY), relative to the zone file")
    p.add_argument("--scale", type=float, help="mesh unit to metres (0.001 for mm)")


# --------------------------------------------------------------------------------------------
# helpers


def late_points(args: argparse.Namespace, extra: list[str]) -> bool:
    """`zones add FILE ID --kind K 'x,y ...'`: argparse gives the optional POINTS up when an
    option comes first and leaves them over; take them as POINTS (True when taken)."""
    if len(extra) == 1 and args.points is None and not extra[0].startswith("-"):
        args.points = extra[0]
        return True
    return False


def _points(text: str, what: str, dims: int = 2) -> list[list[float]]:
    pts = []
    for token in text.replace(";", " ").split():
        pts.append(numbers(token, dims, what))
    if not pts:
        raise ConfigError(f"{what}: no points given")
    return pts


def _find(data: dict, zone_id: str, path: Path) -> int:
    for k, z in enumerate(data.get("zones") or []):
        if isinstance(z, dict) and z.get("id") == zone_id:
            return k
    raise ConfigError(f"{path}: no zone '{zone_id}'")


def _geometry(args: argparse.Namespace, points: str | None) -> dict | None:
    """Shape fields from the command-line options, or None when none is given."""
    given = [name for name, v in (("points", points), ("--box", args.box),
                                  ("--cylinder", args.cylinder), ("--extrude", args.extrude),
                                  ("--mesh", args.mesh)) if v]
    if len(given) > 1:
        raise ConfigError(f"give one geometry, not {' and '.join(given)}")
    if not given:
        return None
    if points:
        return {"shape": "polygon", "points_px": _points(points, "points")}
    if args.box:
        v = numbers(args.box, 6, "--box")
        geom: dict[str, Any] = {"shape": "box", "min_m": v[:3], "max_m": v[3:]}
        if args.yaw:
            geom["yaw_deg"] = args.yaw
        return geom
    if args.cylinder:
        v = numbers(args.cylinder, 5, "--cylinder")
        return {"shape": "cylinder", "center_m": v[:2], "radius_m": v[2], "z_min_m": v[3],
                "z_max_m": v[4]}
    if args.extrude:
        if not args.z:
            raise ConfigError("--extrude needs --z ZMIN,ZMAX")
        z = numbers(args.z, 2, "--z")
        return {"shape": "extrude", "points_m": _points(args.extrude, "--extrude"),
                "z_min_m": z[0], "z_max_m": z[1]}
    geom = {"shape": "mesh", "file": args.mesh}
    if args.scale:
        geom["scale"] = args.scale
    return geom


_SHAPE_FIELDS = {"shape", "camera", "points_px", "anchor", "min_share", "points_m", "z_min_m",
                 "z_max_m", "min_m", "max_m", "yaw_deg", "center_m", "radius_m", "file", "scale"}


def _apply_options(zone: dict, args: argparse.Namespace) -> None:
    if args.name is not None:
        zone["name"] = args.name
    if args.speed_scale is not None:
        zone["speed_scale"] = args.speed_scale
    if zone.get("shape") == "polygon":
        if args.camera is not None:
            zone["camera"] = args.camera  # checked against the file by camera_for
        if args.anchor is not None:
            zone["anchor"] = args.anchor
            if args.anchor != "share":
                zone.pop("min_share", None)
        if args.min_share is not None:
            zone["min_share"] = args.min_share
    elif args.camera or args.anchor or args.min_share is not None:
        raise ConfigError(f"zone '{zone.get('id')}': --camera, --anchor and --min-share are for "
                          "image polygons only")
    if args.yaw is not None and zone.get("shape") == "box":
        zone["yaw_deg"] = args.yaw
    if args.scale is not None and zone.get("shape") == "mesh":
        zone["scale"] = args.scale


# --------------------------------------------------------------------------------------------
# commands


def cmd_new(args: argparse.Namespace) -> int:
    width, height = parse_size(args.size)
    write_new_zone_file(args.file, args.name, [(args.camera, width, height)], force=args.force)
    print(f"created {args.file} with camera {args.camera} ({width}x{height}); more cameras: "
          f"'monitor zones camera add {args.file} ID --size WxH'")
    return 0


def cmd_add(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    geom = _geometry(args, args.points)
    if geom is None:
        raise ConfigError("add: give an image polygon 'x,y x,y ...' or one of --box, "
                          "--cylinder, --extrude, --mesh")
    zone: dict[str, Any] = {"id": args.id, "name": args.name or "", "kind": args.kind}
    if args.disabled:
        zone["enabled"] = False
    zone.update(geom)
    if geom["shape"] == "polygon":
        zone["camera"] = camera_for(data, args)
    _apply_options(zone, args)
    data.setdefault("zones", []).append(zone)
    write_zone_data(data, args.file)
    print(f"added zone {args.id} ({args.kind}, {geom['shape']})")
    return 0


def cmd_edit(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    k = _find(data, args.id, args.file)
    zone = dict(data["zones"][k])
    geom = _geometry(args, args.points)
    if geom is not None:
        keep = {f: zone[f] for f in ("camera", "anchor", "min_share") if f in zone}
        zone = {f: v for f, v in zone.items() if f not in _SHAPE_FIELDS}
        zone.update(geom)
        if geom["shape"] == "polygon":
            zone.update(keep)
            if "camera" not in zone:
                zone["camera"] = camera_for(data, args)
    if zone.get("shape") == "polygon" and args.camera is not None:
        camera_for(data, args)  # a camera the file does not have: the choices and a hint
    if args.kind is not None:
        zone["kind"] = args.kind
        if args.kind != "warning" and args.speed_scale is None:
            zone.pop("speed_scale", None)
    if args.new_id:
        zone["id"] = args.new_id
    _apply_options(zone, args)
    data["zones"][k] = zone
    write_zone_data(data, args.file)
    print(f"edited zone {args.id}")
    return 0


def cmd_remove(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    k = _find(data, args.id, args.file)
    del data["zones"][k]
    write_zone_data(data, args.file)
    print(f"removed zone {args.id}")
    return 0


def cmd_enable(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    for zid in args.ids:
        data["zones"][_find(data, zid, args.file)]["enabled"] = args.enabled
    cell = write_zone_data(data, args.file)
    word = "enabled" if args.enabled else "disabled"
    print(f"{word} {', '.join(args.ids)}; config hash {cell.config_hash}")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    cell = zn.load_cell(args.file)
    rows = [("ID", "KIND", "ON", "SHAPE", "WHERE", "SPEED", "ANCHOR", "NAME")]
    for z in cell.zones:
        where = z.camera if z.shape == "polygon" else "cell"
        speed = f"{z.speed_scale:g}" if z.speed_scale is not None else "-"
        anchor = "-"
        if z.shape == "polygon":
            anchor = z.anchor + (f">={z.min_share:g}" if z.anchor == "share" else "")
        rows.append((z.id, z.kind, "yes" if z.enabled else "no", z.shape, where, speed, anchor,
                     z.name))
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    for r in rows:
        print("  ".join(v.ljust(w) for v, w in zip(r, widths, strict=True)).rstrip())
    print(f"{plural(len(cell.zones), 'zone')}, {plural(len(cell.cameras), 'camera')}, "
          f"config hash {cell.config_hash}")
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    cell = zn.load_cell(args.file)
    z = cell.zone(args.id)
    text = yaml.dump(z.model_dump(mode="json", exclude_none=True), Dumper=zn.ZoneDumper,
                     sort_keys=False)
    print(text.rstrip())
    if z.shape == "polygon":
        area = abs(geo.polygon_signed_area(np.array(z.points_px)))
        print(f"# area {area:.0f} px^2 of camera {z.camera}")
    else:
        v = zn.prepare_volume(z, cell)
        print(f"# bounds_m min {np.round(v.lo, 3).tolist()} max {np.round(v.hi, 3).tolist()}")
        for cam_id in cell.camera_models:
            seen = zn.volume_region_px(z, cell, cell.camera_models[cam_id], cell.cameras[cam_id])
            print(f"# {cam_id}: {'in view' if seen is not None else 'not in view'}")
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    data = zn.read_cell_data(args.file)
    errors, warnings = zn.cell_faults(data, args.file)
    for w in warnings:
        print(f"{args.file}: warning: {w}", file=sys.stderr)
    for e in errors:
        print(f"{args.file}: error: {e}", file=sys.stderr)
    if errors:
        return 2
    cell = zn.parse_cell(data, args.file)
    from monitor.zones.mask_risk import mask_risk_lines

    for grade, line in mask_risk_lines(cell):  # warnings and notes on stderr, ok on stdout
        print(f"{args.file}: {grade}: {line}", file=sys.stdout if grade == "ok" else sys.stderr)
    for cam_id, model in cell.camera_models.items():
        print(f"{args.file}: camera '{cam_id}': {_horizon_text(model)}")
    if args.config is not None:
        from monitor.config import load_config
        from monitor.zones.handover_check import uncalibrated_handover_lines

        config = load_config(args.config)  # a bad config: ConfigError
        for line in uncalibrated_handover_lines(cell, tuple(c.id for c in config.cameras),
                                                tuple(config.handover.peers)):
            print(f"{args.file}: warning: {line}", file=sys.stderr)
    _print_coverage(cell, args.file)
    active = sum(1 for z in cell.zones if z.enabled)
    print(f"{args.file}: ok: {plural(len(cell.zones), 'zone')} ({active} enabled), "
          f"{plural(len(cell.cameras), 'camera')}, config hash {cell.config_hash}")
    return 0


def _print_coverage(cell: zn.Cell, label: object) -> None:
    """What the cameras see of each protective and warning volume (monitor/zones/coverage.py)."""
    from monitor.zones.coverage import zone_coverage
    from monitor.zones.moving import follows_tool, max_zone

    if not cell.camera_models:
        return
    top = cell.spec.person.height_range_m[1]
    for z in cell.zones:
        if z.is_volume and z.enabled and z.kind in ("protective", "warning"):
            if follows_tool(z):  # it may be anywhere in its maximum volume
                z = max_zone(z)
            c = zone_coverage(z, cell.spec, cell.camera_models, cell.meshes)
            print(f"{label}: zone '{z.id}': seen by a camera: "
                  f"{math.floor(100 * (1 - c.unseen_floor_fraction)):d} % of its floor "
                  f"({c.floor_m2:.2f} m² outside occluders), "
                  f"{100 * (1 - c.unseen_volume_fraction):.0f} % of its volume up to {top:g} m")
            if c.hidden_crouch_m2 > c.unseen_floor_m2:
                p = cell.spec.person
                print(f"{label}: zone '{z.id}': a crouching person ({p.smallest_height_m:g} m, "
                      f"{100 * p.needed_fraction:.0f} % in view for the detector) is hidden "
                      f"from every camera on {c.hidden_crouch_m2:.2f} m² "
                      f"({100 * c.hidden_crouch_fraction:.0f} %) of its floor"
                      f"{_floor_extent(c.hidden_crouch_xy_m, c.sample_m)}: a person lost "
                      "there is held until an operator confirms the cell clear "
                      "(docs/occlusion.md)")


def _floor_extent(xy_m: np.ndarray, sample_m: tuple[float, float]) -> str:
    if not len(xy_m):
        return ""
    half = np.asarray(sample_m) / 2
    lo, hi = xy_m.min(axis=0) - half, xy_m.max(axis=0) + half
    return f" (within x {lo[0]:.1f}..{hi[0]:.1f} m, y {lo[1]:.1f}..{hi[1]:.1f} m)"


def _horizon_text(model: geo.CameraModel) -> str:
    """Where the horizon runs in the image: pixels on its far side never meet the floor and
    persons whose feet are there are treated as inside every volume."""
    row = model.horizon_row_px()
    floor = "below" if model.floor_is_below_horizon() else "above"
    if row is None:
        return "horizon not crossing the centre column"
    if row < 0 or row > model.height:
        _, valid = model.pixel_to_floor(np.array([[model.width / 2, model.height / 2]]))
        where = "above" if row < 0 else "below"
        sees = "floor" if valid[0] else "no floor (sky only)"
        return f"horizon {where} the image (row {row:.0f}): the centre column sees {sees}"
    return (f"horizon at row {row:.0f} (centre column): floor {floor} it; a person whose feet "
            f"are beyond it is treated as inside every volume")


def tool_pose_arg(text: str) -> geo.ToolPose:
    """argparse type: 'x,y,z,roll,pitch,yaw' (metres, degrees) as a tracker pose."""
    try:
        v = [float(p) for p in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not six numbers: {text!r}") from None
    if len(v) != 6 or not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"needs six finite numbers x,y,z,roll,pitch,yaw "
                                         f"(metres, degrees), got {text!r}")
    q = geo.matrix_to_quaternion_xyzw(geo.rpy_to_matrix(*v[3:]))
    return geo.ToolPose((v[0], v[1], v[2]), q, 0.0)


def cmd_preview(args: argparse.Namespace) -> int:
    cell = zn.load_cell(args.file)
    camera = choose_camera(cell.cameras, args.camera, str(args.file),
                           zone_file_hint(args.file, args.camera or "ID"))
    frame = cv2.imread(str(args.frame), cv2.IMREAD_COLOR)
    if frame is None:
        raise InputError(f"{args.frame}: cannot read image")
    unknown = [h for h in args.hit if h not in {z.id for z in cell.zones}]
    if unknown:
        raise ConfigError(f"{args.file}: no zone '{unknown[0]}'")
    out = zn.draw_zones(frame, cell, camera, hit_zone_ids=args.hit, legend=True,
                        tool_pose=args.tool_pose)
    hidden, pockets = _draw_hidden(out, cell, camera)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(args.out), out):
        raise InputError(f"{args.out}: cannot write image")
    print(f"wrote {args.out} ({out.shape[1]}x{out.shape[0]}, camera {camera})")
    if hidden:
        print(f"{hidden} foot positions (hatched) are hidden from {camera}: a person lost there "
              "stays held until another camera sees the spot free or an operator confirms "
              "the cell clear (docs/tracking.md)")
        for line in _unseen_lines(cell):
            print(line)
    for k in range(1, pockets + 1):
        print(f"pocket {k} (outlined): hidden floor enclosed by floor {camera} sees; after a "
              "confirm-clear the persons going in and out are counted, and at 0 it is free "
              "without another confirm-clear (docs/tracking.md, \"Hidden pockets\")")
    return 0


def _unseen_lines(cell: zn.Cell) -> list[str]:
    """The protective and warning zones' floor no camera sees, with its cost and a camera
    that would see it (the commissioning report's section, docs/commissioning.md)."""
    # the report's geometry only for a preview that hatched something
    from monitor.commission.unseen import unseen_regions

    out = []
    for r in unseen_regions(cell):
        cam = r["camera"]
        where = (f"; a camera at ({', '.join(f'{v:g}' for v in cam['position_m'])}) m looking "
                 f"from the {cam['from_side']} side would see {100 * cam['sees_share']:.0f} % "
                 "of it") if cam else ""
        out.append(f"unseen floor in {r['kind']} zone {r['zone']}: {r['area_m2']:g} m^2 "
                   f"({100 * r['share']:.0f} % of the zone), {r['hidden_by']}: waiting never "
                   f"ends a hold there{where}")
    return out


def _draw_hidden(image: np.ndarray, cell: zn.Cell, camera: str) -> tuple[int, int]:
    """Hatch the foot positions where this camera cannot see a person (behind an occluder,
    in a mask): the cells a lost person's area never loses by this camera's view; outline the
    enclosed ones (hidden pockets, counted after a confirm-clear, as the replay draws them).
    (hatched cells, pockets)."""
    # the tracker's grid only for a preview: `monitor zones list` starts without it
    from monitor.pipeline.pocket_views import PocketView
    from monitor.records.areas_draw import draw_pockets, hatch_cells
    from monitor.tracking.pockets import find_pockets
    from monitor.tracking.tracks import TrackerConfig
    from monitor.tracking.whereabouts import FootGrid
    from monitor.zones.masks import zone_regions_px
    from monitor.zones.visibility import hidden_feet

    h, w = image.shape[:2]
    grid = FootGrid.of(w, h, TrackerConfig().cells_across)
    masks = [p for _, p in zone_regions_px(cell, camera, ("mask",))]
    model = cell.camera_models.get(camera)
    hidden = hidden_feet(grid.centres(), (w, h), model, cell.spec,
                         cell.meshes, masks).reshape(grid.shape)
    # the look of the replay's and the console's unseen hatching (monitor.records.areas_draw)
    hatched = hatch_cells(image, hidden, grid.cell_px, (w, h))
    # the pockets as the tracker finds them: enclosed by cells whose foot lies on the floor
    floor = None
    if model is not None:
        xy, located = model.pixel_to_floor(grid.centres())
        floor = (np.asarray(located, bool)
                 & np.all(np.isfinite(np.asarray(xy, float)), axis=1)).reshape(grid.shape)
    views = [PocketView(camera, k + 1, cells, None, "not counted before a confirm-clear",
                        grid.cell_px, (w, h))
             for k, cells in enumerate(find_pockets(hidden, floor))]
    draw_pockets(image, views, camera)
    return hatched, len(views)


def cmd_hash(args: argparse.Namespace) -> int:
    print(zn.load_cell(args.file).config_hash)
    return 0


def cmd_calibrate_tool(args: argparse.Namespace) -> int:
    return calibrate_tool(args, read_zone_data, write_zone_data)


