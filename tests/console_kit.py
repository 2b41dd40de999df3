"""What the console tests share: a zone file, a reference image, a real incident recorder's
data dir (a replay with the recorder on: H.264 clips, SQLite index), an operator password."""

from __future__ import annotations

import atexit
import contextlib
import functools
import json
import shutil
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import uvicorn

from monitor.console.app import SERVER_OPTIONS, Console, build_app
from monitor.console.audit import AuditLog
from monitor.console.auth import Operators, set_password
from monitor.console.incidents import NoIncidents
from monitor.console.live import LiveRenderer, LiveState
from monitor.console.zones_api import ZoneEditor
from monitor.incidents import IncidentIndex
from monitor.incidents.store import RECORD, IncidentStore
from tests.helpers import free_port

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


@functools.lru_cache(maxsize=1)
def _recorded() -> Path:
    """A real recorder data dir, made once per test session: the demo cell's replay of a
    person walking into the protective zone (``monitor replay --incidents DIR``'s code path:
    the recorder's worker, its H.264 clips and its SQLite index)."""
    from monitor.models import synthetic

    from monitor.detector import Detector
    from monitor.incidents import RecorderConfig
    from monitor.replay.video import ReplaySettings, replay
    from monitor.scene import DemoScene, write_video
    from monitor.zones import load_cell

    base = Path(tempfile.mkdtemp(prefix="console-incidents-"))
    # the worker's own copy (a 35 MB model, clips): gone when the worker exits, not left in /tmp
    atexit.register(shutil.rmtree, base, True)
    video = base / "walk-in.mp4"
    scene = DemoScene(fps=5.0, duration_s=2.4,
                      path=((0.0, -2.6, -0.3), (1.2, -0.4, -0.3), (9.0, -0.4, -0.3)))
    write_video(video, scene.frames(), scene.fps)
    model = base / "model.onnx"
    synthetic.write_model(model)
    settings = ReplaySettings(out_dir=base / "out", annotate=False, progress=False,
                              incidents_dir=base / "incidents",
                              recorder=RecorderConfig(enabled=True, pre_s=1.0, post_s=0.6))
    replay(video, Detector(model), load_cell(ROOT / "zones" / "demo-cell.yaml"), settings)
    return base / "incidents"


def incident_dir(tmp: Path) -> Path:
    """A copy of a real recorder data dir (index.sqlite3, incident.json, cam0.mp4) with at
    least one incident (stop, latch) whose H.264 clip plays."""
    d = tmp / "incidents"
    shutil.copytree(_recorded(), d)
    return d


def _put_alert(store, base: dict, directory: Path, incident_id: str, wall: float,
               kinds: list[str], clips: dict[str, Path | None]) -> None:
    """An alert incident as the recorder writes it (its folder, incident.json, the row);
    ``clips``: camera -> a clip to copy in (None: named in the record, not there)."""
    folder = directory / incident_id
    folder.mkdir()
    record = {**base, "id": incident_id, "wall": wall, "causes": ["alert"], "alerts": kinds,
              "state": "RUN", "latched": False, "describe": f"{','.join(kinds)} at {wall}",
              "command": {"type": "command", "state": "RUN", "reasons": []}, "clips": {}}
    for camera, source in clips.items():
        record["clips"][camera] = {"file": f"{camera}.mp4", "frames_before": 2}
        if source is not None:
            shutil.copy(source, folder / f"{camera}.mp4")
    (folder / RECORD).write_text(json.dumps(record))
    store.put(record, complete=True)


def review_incidents(directory: Path) -> dict[str, str]:
    """Alert incidents before the recorded STOP of ``incident_dir``'s copy, written by the
    recorder's own store: a camera move whose cam1 clip is missing (500 s before), three mutes
    of cam0 20 s apart (300 s before), a scene change without its clip, a later mute. Their
    ids by name (``stop``, ``moved``, ``mute1``..``mute4``, ``scene``)."""
    (stop,) = IncidentIndex(directory).list()
    clip = stop.clip_paths()["cam0"]
    ids = {"stop": stop.id}
    plan = [("moved", -500, ["camera_moved"], {"cam0": clip, "cam1": None}),
            ("mute1", -300, ["zone_muted"], {"cam0": clip}),
            ("mute2", -280, ["zone_muted"], {"cam0": clip}),
            ("mute3", -260, ["zone_muted"], {"cam0": clip}),
            ("scene", -200, ["scene_change"], {"cam0": None}),
            ("mute4", -100, ["zone_muted"], {"cam0": clip})]
    store = IncidentStore(directory)
    try:
        for name, dt, kinds, clips in plan:
            ids[name] = f"20261128T000000Z-test-{name}"
            _put_alert(store, stop.record, directory, ids[name], stop.wall + dt, kinds, clips)
    finally:
        store.close()
    return ids


def passwords(tmp: Path) -> Path:
    path = tmp / "console.passwords"
    set_password(path, OPERATOR, PASSWORD)
    return path


def basic(name: str, password: str) -> dict:
    """The header the zone editor's script sends."""
    import base64

    token = base64.b64encode(f"{name}:{password}".encode()).decode()
    return {"authorization": "Basic " + token}


def make_console(tmp: Path, with_passwords: bool = True, **options):
    """The real app's ``Console`` over a zone file, a real recorder data dir (zone edits are
    incidents there) and a passwords file; ``options``: other ``Console`` fields."""
    from monitor.console.edits import ZoneEditIncidents
    from monitor.console.incidents import RecorderIncidents

    cell = zone_file(tmp)
    editor = ZoneEditor(cell)
    live = LiveState()
    incidents = incident_dir(tmp)
    fields = {"audit": AuditLog(tmp / "audit.jsonl"),
              "operators": Operators(passwords(tmp) if with_passwords else None), **options}
    return Console("c", live, LiveRenderer(live, editor.cell, {}), editor,
                   RecorderIncidents(incidents), references={},
                   edits=ZoneEditIncidents(incidents, "c"), **fields)


def plain_console(d: Path, **options):
    """A ``Console`` over ``d/cell.yaml`` and the passwords file ``d/pw`` without a recorder;
    its audit log is ``d/audit.jsonl``."""
    editor = ZoneEditor(d / "cell.yaml")
    live = LiveState()
    return Console("c", live, LiveRenderer(live, editor.cell, {}), editor, NoIncidents(),
                   Operators(d / "pw"), AuditLog(d / "audit.jsonl"), {}, **options)


def audit_lines(d: Path) -> list[dict]:
    """The audit log of a ``plain_console`` over ``d``."""
    return [json.loads(line) for line in (d / "audit.jsonl").read_text().splitlines()]


@contextlib.contextmanager
def serving(console):
    """The app in a real uvicorn on 127.0.0.1 (its own thread); yields the base URL."""
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(build_app(console), host="127.0.0.1", port=port,
                                           log_level="warning", timeout_graceful_shutdown=1,
                                           **SERVER_OPTIONS))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30.0
    while not server.started:
        assert time.monotonic() < deadline, "uvicorn did not start within 30 s"
        assert thread.is_alive(), "uvicorn exited at start"
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(30.0)


CHROMIUM = Path("/usr/bin/chromium")


@contextlib.contextmanager
def chromium(profile: Path):
    """A real headless chromium driven by selenium (Debian's chromium + chromium-driver)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run",
                 "--disable-dev-shm-usage", "--autoplay-policy=no-user-gesture-required",
                 f"--user-data-dir={profile}",
                 "--window-size=1400,1000"):
        opts.add_argument(flag)
    driver = webdriver.Chrome(options=opts, service=Service(
        shutil.which("chromedriver") or "/usr/bin/chromedriver"))
    driver.set_page_load_timeout(30)
    try:
        yield driver
    finally:
        driver.quit()


def wait_http(url: str, proc, log: Path, ceiling: float = 60.0) -> None:
    """Until ``url`` answers (the console process ``proc`` is up), its log on failure."""
    import time
    import urllib.request

    deadline = time.monotonic() + ceiling
    while time.monotonic() < deadline:
        assert proc.poll() is None, log.read_text()
        try:
            urllib.request.urlopen(url, timeout=1).read()
            return
        except OSError:
            time.sleep(0.2)
    raise AssertionError(f"{url} did not answer within {ceiling:g} s: {log.read_text()}")
