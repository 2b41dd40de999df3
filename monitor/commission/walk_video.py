"""``monitor commission walk --video``: the walk test on a recorded video, through replay's own
machinery (``monitor.replay.video.replay``: the service's driver and pipeline on the video's clock),
with a ``WalkRecorder`` on its step callback. Writes into DIR: ``walk.json`` (the result),
``floor.png``, ``camera-<id>.png``, and replay's ``events.jsonl``, ``summary.json`` and
``annotated.mp4`` (the evidence behind every figure).

The policy runs with ``restart_interlock = "auto"`` so that each entry gets its own STOP (with
the manual interlock the first STOP would hold for the whole walk and every later entry would
find it already there); everything else is the configuration's.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np

from monitor.commission.floor import CELL_M, ZoneFloor, zone_floors
from monitor.commission.pictures import camera_picture, floor_picture
from monitor.commission.truth import read_truth
from monitor.commission.walk import WalkRecorder, WalkResult, analyse
from monitor.errors import InputError
from monitor.replay.video import ReplaySettings, replay
from monitor.zones import Cell
from monitor.zones.cameras import choose_camera

WALK_FILE = "walk.json"


def walk_video(video: str | Path, detector, cell: Cell, settings: ReplaySettings,
               cell_m: float = CELL_M, truth: Path | None = None,
               recording: dict | None = None) -> tuple[WalkResult, dict[str, str]]:
    """Replay ``video`` with the walk recorder; (result, {picture name: file name}) and the
    files in ``settings.out_dir``. ``truth``: the video's ground truth (``truth.json`` of a
    generated walk), read before the replay so that a bad file fails at once; ``recording``:
    the figures of ``--record`` (kept in walk.json)."""
    frames = read_truth(truth) if truth is not None else None
    camera_id = choose_camera(cell.cameras, settings.camera_id, cell.label)
    policy = dataclasses.replace(settings.policy, restart_interlock="auto")
    settings = dataclasses.replace(settings, policy=policy, camera_id=camera_id)
    band = (0.0, detector.foot_uncertainty_px(cell.cameras[camera_id].width,
                                              cell.cameras[camera_id].height))
    recorder = WalkRecorder(cell, {camera_id: settings.reference}, band)
    replay(video, detector, cell, settings, publish=recorder)
    floors = zone_floors(cell, cell_m)
    alarm_images = [(z.id, z.kind) for z in cell.zones
                    if z.enabled and z.kind in ("protective", "warning") and not z.is_volume]
    result = analyse(recorder.samples, floors, alarm_images, frames, str(truth))
    out = settings.out_dir
    pictures = write_pictures(out, cell, floors, result, {camera_id: first_frame(video)})
    data = {"video": Path(video).name, "camera": camera_id, "zones_hash": cell.config_hash,
            "truth": Path(truth).name if truth is not None else None,
            "recording": recording,
            **result.to_dict(), "pictures": pictures}
    (out / WALK_FILE).write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    return result, pictures


def write_pictures(out: Path, cell: Cell, floors: list[ZoneFloor], result: WalkResult | None,
                   images: dict[str, np.ndarray]) -> dict[str, str]:
    """floor.png and camera-<id>.png in ``out``; {name: file name}."""
    names = {"floor": "floor.png"}
    (out / "floor.png").write_bytes(floor_picture(cell, floors, result))
    for camera_id, image in sorted(images.items()):
        name = f"camera-{camera_id}.png"
        (out / name).write_bytes(camera_picture(image, cell, camera_id, floors, result))
        names[f"camera {camera_id}"] = name
    return names


def first_frame(video: str | Path) -> np.ndarray:
    """The video's first frame (the camera picture's background)."""
    cap = cv2.VideoCapture(str(video))
    try:
        ok, image = cap.read()
    finally:
        cap.release()
    if not ok:
        raise InputError(f"{video}: no frame could be read")
    return image


def read_walk(folder: Path) -> dict:
    """walk.json of a walk folder, with one-line errors."""
    path = Path(folder) / WALK_FILE
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no walk result here (run `monitor commission walk` "
                         "first)") from None
    except (ValueError, UnicodeDecodeError):
        raise InputError(f"{path}: not a walk result (not JSON)") from None
    if not isinstance(data, dict) or not isinstance(data.get("zones"), list):
        raise InputError(f"{path}: not a walk result (no zones)")
    return data
