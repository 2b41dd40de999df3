"""``monitor zones camera add|remove|set|list``: the cameras of a zone file from the command line.

Like every zone edit: validated before anything is written, atomic, FILE.bak kept, the file's
comments and indentation kept. A camera's zones are in its pixels: removing a camera that still
has image polygons, or changing its size under polygons or a calibration, is refused unless the
command says what to do with them.
"""

from __future__ import annotations

import argparse
import os
import re
from pathlib import Path
from typing import Any

import cv2
import yaml

from monitor import zones as zn
from monitor.cli.zone_files import document_defaults, plural, read_zone_data, write_zone_data
from monitor.errors import ConfigError
from monitor.zones.cameras import choose_camera, zone_file_hint

HEADER = "workcell-monitor zone file (format: zones/README.md). Edit with 'monitor zones'."


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("camera", help="add, remove, change or list the cameras of a zone "
                            "file")
    actions = parser.add_subparsers(dest="camera_action", metavar="ACTION", required=True,
                                    help="add, remove, set or list")

    p = actions.add_parser("add", help="add a camera")
    p.add_argument("file", type=Path)
    p.add_argument("camera", help="camera id, as in monitor.toml's [[camera]] id")
    p.add_argument("--size", help="camera resolution WxH, e.g. 1280x720 (required unless "
                   "--source is a video or image file: its size is read)")
    p.add_argument("--calibration", type=Path,
                   help="YAML file holding a calibration mapping (zones/README.md)")
    p.add_argument("--source", help="the camera's source (index, rtsp:// URL, video file)")
    p.add_argument("--config", type=Path,
                   help="monitor.toml to add the camera to as a [[camera]] table with --source "
                   "(a camera in the zone file that no [[camera]] feeds is refused by 'monitor "
                   "run' once it has zones)")
    p.set_defaults(func=cmd_camera_add)

    p = actions.add_parser("remove", help="remove a camera")
    p.add_argument("file", type=Path)
    p.add_argument("camera", help="camera id")
    p.add_argument("--with-zones", action="store_true",
                   help="also remove the camera's image polygons (refused without)")
    p.set_defaults(func=cmd_camera_remove)

    p = actions.add_parser("set", help="change a camera's id, size, calibration or reference")
    p.add_argument("file", type=Path)
    p.add_argument("camera", nargs="?",
                   help="camera id (default: the file's only camera; required when it has "
                   "several)")
    p.add_argument("--new-id", help="rename the camera (its image polygons follow)")
    p.add_argument("--size", help="new resolution WxH")
    p.add_argument("--rescale", action="store_true",
                   help="with --size: scale the camera's polygons and calibration pixels to the "
                   "new size (the same view, resized); refused without when it has any")
    cal = p.add_mutually_exclusive_group()
    cal.add_argument("--calibration", type=Path,
                     help="YAML file holding a calibration mapping (zones/README.md)")
    cal.add_argument("--no-calibration", action="store_true",
                     help="remove the camera's calibration")
    ref = p.add_mutually_exclusive_group()
    ref.add_argument("--reference", type=Path,
                     help="the camera's reference image for the health checks ('monitor "
                     "reference capture'), of the camera's size; stored relative to the zone "
                     "file, and used instead of monitor.toml's [[camera]] reference")
    ref.add_argument("--no-reference", action="store_true",
                     help="remove the camera's reference from the zone file")
    p.set_defaults(func=cmd_camera_set)

    p = actions.add_parser("list", help="list the cameras")
    p.add_argument("file", type=Path)
    p.set_defaults(func=cmd_camera_list)

    for action in actions.choices.values():
        document_defaults(action, "not set")


def source_kind(spec: str) -> str:
    """``monitor.frames.source_kind``, imported on first use: the frames package loads the
    video readers and the demo scene, which `monitor zones list` does not need."""
    from monitor.frames import source_kind as kind

    return kind(spec)


def parse_size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise ConfigError(f"--size: expected WxH such as 1280x720, got {text!r}")
    return int(m[1]), int(m[2])


def new_zone_document(name: str, cameras: list[tuple[str, int, int]]) -> Any:
    """A new zone file's document (cameras, no zones yet), in the zones/ files' layout."""
    from ruamel.yaml.comments import CommentedMap

    doc = CommentedMap(version=zn.SCHEMA_VERSION, name=name,
                       cameras=[{"id": c, "width": w, "height": h} for c, w, h in cameras],
                       zones=[])
    doc.yaml_set_start_comment(HEADER)
    return doc


def write_new_zone_file(path: Path, name: str, cameras: list[tuple[str, int, int]],
                        force: bool = False) -> zn.Cell:
    if path.exists() and not force:
        raise ConfigError(f"{path}: file exists (use --force to overwrite)")
    return write_zone_data(new_zone_document(name, cameras), path)


def _camera_ids(data: dict) -> list[str]:
    return [c.get("id") for c in data.get("cameras") or [] if isinstance(c, dict)]


def camera_entry(data: dict, camera: str | None, path: Path) -> dict:
    chosen = choose_camera(_camera_ids(data), camera, str(path),
                           zone_file_hint(path, camera or "ID"))
    return next(c for c in data["cameras"] if isinstance(c, dict) and c.get("id") == chosen)


def _polygons(data: dict, camera: str) -> list[dict]:
    return [z for z in data.get("zones") or []
            if isinstance(z, dict) and z.get("shape") == "polygon" and z.get("camera") == camera]


def _read_calibration(path: Path) -> dict:
    try:
        cal = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not YAML: {str(exc).splitlines()[0]}") from None
    if isinstance(cal, dict) and isinstance(cal.get("calibration"), dict):
        cal = cal["calibration"]  # a camera entry copied from another zone file
    if not isinstance(cal, dict) or "type" not in cal:
        raise ConfigError(f"{path}: expected a calibration mapping with 'type: homography' or "
                          "'type: pinhole' (zones/README.md)")
    return cal


def media_size(path: Path, what: str) -> tuple[int, int]:
    """Width and height of a video or image file (its first frame)."""
    if not path.is_file():
        raise ConfigError(f"{what}: {path}: no such file")
    image = cv2.imread(str(path)) if source_kind(str(path)) == "image" else None
    if image is not None:
        return image.shape[1], image.shape[0]
    cap = cv2.VideoCapture(str(path))
    try:
        ok, frame = cap.read()
    finally:
        cap.release()
    if not ok or frame is None:
        raise ConfigError(f"{what}: {path}: cannot read a frame (not a video?)")
    return frame.shape[1], frame.shape[0]


def _config_with_camera(args: argparse.Namespace, width: int, height: int) -> str:
    """monitor.toml's text with the new camera's [[camera]] table, validated."""
    import tomllib

    from monitor.cli.deploykit import KitCamera, add_camera_table
    from monitor.config import parse_config

    path: Path = args.config
    if args.source is None:
        raise ConfigError("zones camera add --config: give the camera's --source too")
    try:
        text = path.read_text(encoding="utf-8")
        config = parse_config(tomllib.loads(text), str(path), path.parent)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    if args.camera in {c.id for c in config.cameras}:
        raise ConfigError(f"{path}: has a [[camera]] '{args.camera}' already")
    source = args.source
    if source_kind(source) in ("file", "image"):
        source = str(Path(source).expanduser().resolve())
    live = source_kind(source) in ("camera", "url")
    new = add_camera_table(text, KitCamera(args.camera, source, width, height, live), str(path))
    parse_config(tomllib.loads(new), str(path), path.parent)  # still valid: else nothing written
    return new


def _write_text_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.chmod(tmp, path.stat().st_mode & 0o7777)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise ConfigError(f"{path}: cannot write: {exc.strerror}") from None


def cmd_camera_add(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    if args.camera in _camera_ids(data):
        raise ConfigError(f"{args.file}: camera '{args.camera}' exists already (change it with "
                          f"'monitor zones camera set {args.file} {args.camera}')")
    if args.size:
        width, height = parse_size(args.size)
    elif args.source and source_kind(args.source) in ("file", "image"):
        width, height = media_size(Path(args.source).expanduser(), f"--source {args.source}")
    else:
        raise ConfigError(f"zones camera add: say the resolution of camera '{args.camera}' with "
                          "--size WxH")
    cam: dict[str, Any] = {"id": args.camera, "width": width, "height": height}
    if args.calibration is not None:
        cam["calibration"] = _read_calibration(args.calibration)
    config_text = _config_with_camera(args, width, height) if args.config else None
    data.setdefault("cameras", []).append(cam)
    cell = write_zone_data(data, args.file)
    if config_text is not None:
        _write_text_atomic(args.config, config_text)
        print(f"added [[camera]] {args.camera} ({args.source}) to {args.config}")
    print(f"added camera {args.camera} ({width}x{height}); {plural(len(cell.cameras), 'camera')}"
          f", config hash {cell.config_hash}")
    return 0


def cmd_camera_remove(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    cam = camera_entry(data, args.camera, args.file)
    polygons = _polygons(data, args.camera)
    if polygons and not args.with_zones:
        raise ConfigError(f"{args.file}: camera '{args.camera}' has image zones "
                          f"{', '.join(z['id'] for z in polygons)}: remove them first or use "
                          "--with-zones")
    if len(_camera_ids(data)) == 1:
        raise ConfigError(f"{args.file}: '{args.camera}' is the only camera: a zone file needs "
                          "one (add the new one first)")
    data["cameras"].remove(cam)
    for z in polygons:
        data["zones"].remove(z)
    write_zone_data(data, args.file)
    gone = f" and its zones {', '.join(z['id'] for z in polygons)}" if polygons else ""
    print(f"removed camera {args.camera}{gone}")
    return 0


def _rescale(cam: dict, polygons: list[dict], sx: float, sy: float) -> None:
    """Pixels of the same view at another resolution: polygons, homography pairs (u, v) and
    the camera matrix (fx, cx by sx; fy, cy by sy)."""
    for z in polygons:
        z["points_px"] = [[round(p[0] * sx, 3), round(p[1] * sy, 3)] for p in z["points_px"]]
    cal = cam.get("calibration")
    if not isinstance(cal, dict):
        return
    if cal.get("pairs"):
        cal["pairs"] = [[p[0] * sx, p[1] * sy, *p[2:]] for p in cal["pairs"]]
    k = cal.get("camera_matrix")
    if k:
        cal["camera_matrix"] = [[k[0][0] * sx, k[0][1] * sx, k[0][2] * sx],
                                [k[1][0] * sy, k[1][1] * sy, k[1][2] * sy], list(k[2])]


def reference_entry(zone_file: Path, image_path: Path, camera: str, width: int,
                    height: int) -> str:
    """The zone file's ``reference:`` value for an image: checked to be a readable image of
    the camera's size, its path relative to the zone file. One-line ConfigError otherwise."""
    from monitor.health.references import require_size

    if not image_path.is_file():
        raise ConfigError(f"--reference {image_path}: no such file (make one with 'monitor "
                          "reference capture')")
    image = cv2.imread(str(image_path), cv2.IMREAD_COLOR)
    if image is None:
        raise ConfigError(f"--reference {image_path}: not a readable image")
    require_size(image, width, height, f"camera '{camera}': --reference {image_path}")
    rel = os.path.relpath(image_path.resolve(), zone_file.resolve().parent)
    return Path(rel).as_posix()


def cmd_camera_set(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    cam = camera_entry(data, args.camera, args.file)
    camera = cam["id"]
    polygons = _polygons(data, camera)
    changed = []
    if args.size:
        width, height = parse_size(args.size)
        if (width, height) != (cam.get("width"), cam.get("height")):
            if (polygons or cam.get("calibration")) and not args.rescale:
                raise ConfigError(f"{args.file}: camera '{camera}' has image zones or a "
                                  "calibration in pixels of "
                                  f"{cam.get('width')}x{cam.get('height')}: add --rescale (the "
                                  "same view, resized) or calibrate and draw them again")
            if cam.get("reference") and args.reference is None and not args.no_reference:
                raise ConfigError(f"{args.file}: camera '{camera}' has a reference image of "
                                  f"{cam.get('width')}x{cam.get('height')}: give a new one "
                                  "with --reference (or --no-reference)")
            _rescale(cam, polygons, width / cam["width"], height / cam["height"])
            cam["width"], cam["height"] = width, height
            changed.append(f"size {width}x{height}")
    if args.reference is not None:
        cam["reference"] = reference_entry(args.file, args.reference, camera, cam["width"],
                                           cam["height"])
        changed.append(f"reference {cam['reference']}")
    if args.no_reference and "reference" in cam:
        del cam["reference"]
        changed.append("no reference")
    if args.calibration is not None:
        cam["calibration"] = _read_calibration(args.calibration)
        changed.append("calibration")
    if args.no_calibration:
        cam.pop("calibration", None)
        changed.append("no calibration")
    if args.new_id:
        if args.new_id in _camera_ids(data):
            raise ConfigError(f"{args.file}: camera '{args.new_id}' exists already")
        cam["id"] = args.new_id
        for z in polygons:
            z["camera"] = args.new_id
        changed.append(f"id {args.new_id}")
    if not changed:
        raise ConfigError("camera set: nothing to change (give --size, --calibration, "
                          "--no-calibration, --reference, --no-reference or --new-id)")
    cell = write_zone_data(data, args.file)
    print(f"camera {camera}: {', '.join(changed)}; config hash {cell.config_hash}")
    return 0


def cmd_camera_list(args: argparse.Namespace) -> int:
    cell = zn.load_cell(args.file)
    rows = [("ID", "SIZE", "CALIBRATION", "IMAGE ZONES", "REFERENCE")]
    for cam in cell.cameras.values():
        n = sum(1 for z in cell.zones if z.shape == "polygon" and z.camera == cam.id)
        rows.append((cam.id, f"{cam.width}x{cam.height}",
                     cam.calibration.type if cam.calibration is not None else "-", str(n),
                     cam.reference or "-"))
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    for r in rows:
        print("  ".join(v.ljust(w) for v, w in zip(r, widths, strict=True)).rstrip())
    return 0
