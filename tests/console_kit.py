"""What the console tests share: a zone file, a reference image, an incident directory with
a real H.264 clip (PyAV, libx264) and the placeholder index, and an operator password."""

from __future__ import annotations

import shutil
import sqlite3
import time
from pathlib import Path

import cv2
import numpy as np

from monitor.console.auth import set_password

ROOT = Path(__file__).resolve().parents[1]
OPERATOR, PASSWORD = "anna", "correct horse battery"


def zone_file(tmp: Path) -> Path:
    """The demo cell (comments and all), as a user's zone file."""
    path = tmp / "cell.yaml"
    shutil.copy(ROOT / "zones" / "demo-cell.yaml", path)
    return path


def reference_image(tmp: Path, person: bool = False) -> Path:
    """A 1280x720 'camera image': floor, robot base, optionally a magenta figure."""
    img = np.full((720, 1280, 3), (90, 100, 110), np.uint8)
    img[:330] = (150, 140, 130)
    cv2.rectangle(img, (590, 380), (690, 520), (60, 60, 60), -1)
    if person:
        cv2.rectangle(img, (610, 330), (660, 500), (255, 0, 255), -1)
    path = tmp / ("snapshot.png" if person else "reference.png")
    cv2.imwrite(str(path), img)
    return path


def h264_clip(path: Path, frames: int = 40, fps: int = 10) -> Path:
    import av

    with av.open(str(path), "w", options={"movflags": "faststart"}) as out:
        stream = out.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = 320, 240, "yuv420p"
        for k in range(frames):
            img = np.zeros((240, 320, 3), np.uint8)
            cv2.rectangle(img, (10 + 6 * k, 80), (60 + 6 * k, 200), (255, 0, 255), -1)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path


def incident_dir(tmp: Path) -> Path:
    """The placeholder layout: DIR/index.sqlite with two incidents, one with a clip."""
    d = tmp / "incidents"
    (d / "clips").mkdir(parents=True)
    h264_clip(d / "clips" / "inc-1.mp4")
    now = time.time()
    with sqlite3.connect(d / "index.sqlite") as db:
        db.execute("CREATE TABLE incidents (id TEXT PRIMARY KEY, started REAL, cause TEXT, "
                   "state TEXT, camera TEXT, clip TEXT)")
        db.executemany("INSERT INTO incidents VALUES (?, ?, ?, ?, ?, ?)", [
            ("inc-1", now - 60, "protective_zone", "STOP", "cam0", "clips/inc-1.mp4"),
            ("inc-2", now - 30, "camera_lost", "STOP", "cam1", None),
        ])
    return d


def passwords(tmp: Path) -> Path:
    path = tmp / "console.passwords"
    set_password(path, OPERATOR, PASSWORD)
    return path
