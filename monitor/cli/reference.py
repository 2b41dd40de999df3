"""``monitor reference capture``: store a camera's reference image for the health checks.

Take one at commissioning and again after every deliberate change in the cell (a new fixture in
a watch zone, a camera remounted on purpose): the "moved" and "defocused" checks and the watch
zones' backgrounds start from it. Capture with the cell empty; the per-pixel median of several
frames removes sensor noise and anything that only passes through.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from monitor.errors import InputError
from monitor.frames import open_source


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "reference", help="reference images for the camera health checks",
        description="Reference images for the camera health checks (moved, defocused, watch "
        "zones).")
    actions = parser.add_subparsers(dest="reference_action", metavar="ACTION", required=True)
    capture = actions.add_parser(
        "capture", help="store a new reference image of a camera",
        description="Store the per-pixel median of the first frames of SOURCE as the camera's "
        "reference image (written atomically: readers see the old or the new file, never half).")
    capture.add_argument("--config", type=Path,
                         help="monitor.toml: take the camera's source and its [camera] "
                         "reference path from it (default: none; then --source and --out)")
    capture.add_argument("--camera",
                         help="camera id: with --config the config's only camera by default "
                         "(required when it has several); without, it names the image in an "
                         "--out directory")
    capture.add_argument("--source",
                         help="video file, image, camera index, rtsp:// URL or synthetic:demo "
                         "(default: the camera's source in --config)")
    capture.add_argument("--out", type=Path,
                         help="image file to write (PNG recommended); a directory (or a name "
                         "without suffix) gets <camera>.png (default: the camera's reference "
                         "in --config)")
    capture.add_argument("--zones", type=Path,
                         help="zone file: store the image as the camera's reference there "
                         "(written to its entry's reference path, or --out; the image must "
                         "have the camera's size); the zone file's reference is the one the "
                         "service uses (default: none)")
    capture.add_argument("--frames", type=int, default=15,
                         help="median of this many frames (default 15; 1 = a single frame)")
    capture.set_defaults(func=_capture)


def capture_reference(source: str, camera_id: str, frames: int) -> tuple[np.ndarray, int]:
    """Per-pixel median (BGR uint8) of the first ``frames`` frames of a source, and how many
    frames it used (fewer when the source ends early)."""
    if frames < 1:
        raise InputError(f"--frames must be >= 1, got {frames}")
    src = open_source(source, camera_id, realtime=False)
    images: list[np.ndarray] = []
    try:
        while len(images) < frames:
            frame = src.read()
            if frame is None:
                break
            if images and frame.image.shape != images[0].shape:
                raise InputError(f"{src.description}: frame size changed while capturing")
            images.append(frame.image)
    finally:
        src.close()
    if not images:
        raise InputError(f"{src.description}: no frame could be read")
    if len(images) == 1:
        return images[0].copy(), 1
    return np.median(np.stack(images), axis=0).round().astype(np.uint8), len(images)


def write_image_atomic(path: Path, image: np.ndarray) -> None:
    """Encode by the file's suffix and replace ``path`` in one step (temp file + rename)."""
    suffix = path.suffix.lower()
    try:
        ok, buf = cv2.imencode(suffix, image)
    except cv2.error:
        ok = False
    if not ok:
        raise InputError(f"{path}: cannot write images of type {suffix!r} (use .png)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o644)  # mkstemp makes 0600; the service may run as another user
        with os.fdopen(fd, "wb") as f:
            f.write(buf.tobytes())
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _zone_camera_out(args: argparse.Namespace) -> tuple[str, Path | None]:
    """With --zones: the zone file's camera (the one --camera rule) and the image to write:
    --out, else the reference the camera's entry names (None: neither)."""
    from monitor.health.references import zone_file_reference
    from monitor.zones import load_cell
    from monitor.zones.cameras import choose_camera, zone_file_hint

    cell = load_cell(args.zones)
    camera = choose_camera(cell.cameras, args.camera, str(args.zones),
                           zone_file_hint(args.zones, args.camera or "ID"))
    return camera, args.out or zone_file_reference(cell, camera)


def _camera_source_out(args: argparse.Namespace) -> tuple[str, str, Path]:
    """Camera id, source and output image, by the one --camera rule (monitor.zones.cameras)."""
    source, out, camera = args.source, args.out, args.camera
    if args.zones is not None:
        camera, out = _zone_camera_out(args)
        if out is None:
            raise InputError(f"{args.zones}: camera '{camera}' has no reference yet: say where "
                             "to write it with --out")
    if args.config is not None:
        from monitor.config import load_config
        from monitor.zones.cameras import choose_camera

        config = load_config(args.config)
        cams = {c.id: c for c in config.cameras}
        camera = choose_camera(cams, camera, str(args.config))
        source = source or cams[camera].source
        if out is None and cams[camera].reference is None:
            raise InputError(f"{args.config}: camera '{camera}' has no reference path: set "
                             "its reference or give --out")
        out = out or Path(cams[camera].reference)
    if source is None or out is None:
        raise InputError("reference capture: give --config, or --source and --out")
    if out.is_dir() or not out.suffix:
        if camera is None:
            raise InputError(f"--out {out} is a directory: say which camera with --camera "
                             "(the image is named <camera>.png)")
        out = out / f"{camera}.png"
    return camera or out.stem, source, out


def _store_in_zone_file(zones: Path, camera: str, out: Path) -> str | None:
    """Name ``out`` as the camera's reference in the zone file (an atomic zone edit, FILE.bak
    kept); None when it names it already."""
    from monitor.cli.zone_cameras import camera_entry, reference_entry
    from monitor.cli.zone_files import read_zone_data, write_zone_data

    data = read_zone_data(zones)
    cam = camera_entry(data, camera, zones)
    entry = reference_entry(zones, out, camera, cam["width"], cam["height"])
    if cam.get("reference") == entry:
        return None
    cam["reference"] = entry
    return write_zone_data(data, zones).config_hash


def _capture(args: argparse.Namespace) -> int:
    from monitor.health.references import require_size

    camera, source, out = _camera_source_out(args)
    image, used = capture_reference(source, camera, args.frames)
    if args.zones is not None:  # refuse a wrong size before anything is written
        from monitor.zones import load_cell

        cam = load_cell(args.zones).cameras[camera]
        require_size(image, cam.width, cam.height, f"the image of {source}")
    try:
        write_image_atomic(out, image)
    except OSError as exc:
        raise InputError(f"{out}: cannot write: {exc.strerror or exc}") from exc
    height, width = image.shape[:2]
    print(f"{out}: reference of camera {camera} ({width}x{height}, median of {used} "
          f"frame{'s' if used != 1 else ''} from {source})")
    if args.zones is not None:
        new_hash = _store_in_zone_file(args.zones, camera, out)
        if new_hash is not None:
            print(f"{args.zones}: camera {camera} reference set; config hash {new_hash}")
    return 0
