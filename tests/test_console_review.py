"""Reviewing incidents in the console: each listed incident with a clip shows a thumbnail,
the clip's frame at the incident's moment (``/api/incidents/{id}/thumb.jpg``), decoded from
the real recorder's H.264 clip; a forged record or an unknown id gives none."""

from __future__ import annotations

import cv2
import numpy as np
from starlette.testclient import TestClient

from monitor.console.app import build_app
from monitor.console.incidents import IncidentFilters, RecorderIncidents, clip_thumbnail
from monitor.incidents import IncidentIndex
from monitor.incidents.store import IncidentStore
from tests.console_kit import make_console


def test_every_incident_with_a_clip_has_a_thumbnail_of_its_moment(tmp_path):
    console = make_console(tmp_path)
    client = TestClient(build_app(console))
    (row,) = client.get("/api/incidents").json()["incidents"]
    assert row["has_clip"]
    r = client.get(f"/api/incidents/{row['id']}/thumb.jpg")
    assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
    thumb = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
    assert thumb.shape == (135, 240, 3)  # the 1280x720 clip at 240 px
    # the frame of the moment the incident began (the clip's frames_before), not its first
    (incident,) = IncidentIndex(console.incidents.directory).list()
    clip = incident.clip_paths()["cam0"]
    at = incident.record["clips"]["cam0"]["frames_before"]
    assert at > 0 and r.content == clip_thumbnail(clip, at) != clip_thumbnail(clip, 0)
    assert client.get(f"/api/incidents/{row['id']}/thumb.jpg?camera=cam1").status_code == 404
    assert client.get("/api/incidents/nothing/thumb.jpg").status_code == 404
    # served from memory the second time (the same bytes), bounded by MAX_THUMBS
    assert client.get(f"/api/incidents/{row['id']}/thumb.jpg").content == r.content


def test_a_forged_record_gets_no_thumbnail(tmp_path):
    console = make_console(tmp_path)
    src = console.incidents
    assert isinstance(src, RecorderIncidents)
    (real,) = IncidentIndex(src.directory).list()
    (tmp_path / "secret.mp4").write_bytes((src.directory / real.id / "cam0.mp4").read_bytes())
    (src.directory / "evil").mkdir()
    store = IncidentStore(src.directory)  # another row, written by the recorder's own store
    try:
        store.put({**real.record, "id": "evil", "wall": real.wall - 60,
                   "clips": {"cam0": {"file": "../../secret.mp4", "frames_before": 0}}},
                  complete=True)
    finally:
        store.close()
    assert [i["id"] for i in src.list(IncidentFilters())][-1] == "evil"
    assert src.thumbnail("evil") is None and src.thumbnail(real.id) is not None
