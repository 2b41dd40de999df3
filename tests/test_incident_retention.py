"""Issue 31, part 1: retention never deletes a safety incident (STOP, latch, refused reset) to
make room for anything else: at its limits it deletes the others, oldest first, then keeps the
safety incidents and says so (an alert over ``max_gb``; recording stops below the disk floor).
Real SQLite index, real folders, a real recorder data dir from a replay, the real recorder."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from starlette.testclient import TestClient

from monitor.console.app import build_app
from monitor.driver import Step
from monitor.frames import Frame
from monitor.incidents import IncidentIndex, RecorderConfig
from monitor.incidents.recorder import BLOCKED_ALERT, IncidentRecorder
from monitor.incidents.retention import GB, SAFETY_CAUSES, DiskFloor, enforce
from monitor.incidents.store import IncidentStore
from monitor.pipeline import StepResult
from monitor.policy import Command, Reason
from monitor.types import FrameInfo
from tests.console_kit import OPERATOR, PASSWORD, basic, make_console

BOWTIE = [[900, 150], [1200, 400], [1200, 150], [900, 400]]


def _put(store: IncidentStore, incident_id: str, wall: float, causes: tuple[str, ...],
         size: int) -> None:
    (store.data_dir / incident_id).mkdir()
    (store.data_dir / incident_id / "cam0.mp4").write_bytes(b"clip")
    store.put({"id": incident_id, "wall": wall, "time_s": 0.0, "cell": "c",
               "causes": list(causes), "state": "STOP", "latched": False, "describe": "",
               "reset": None, "zones_hash": "z", "config_hash": "c"}, size=size,
              complete=True)


def test_retention_at_its_limit_keeps_every_safety_incident(tmp_path):
    store = IncidentStore(tmp_path)
    now = time.time()
    kinds = [("stop", "latch"), ("alert",), ("zone_edit",), ("reset_refused",), ("fault",),
             ("reset_accepted",), ("stop", "alert"), ("alert",), ("zone_edit",)]
    for k, causes in enumerate(kinds):  # oldest first: the STOP is the oldest of all
        _put(store, f"i{k}", now - 3600 + k, causes, GB // 4)
    safety = {f"i{k}" for k, c in enumerate(kinds) if SAFETY_CAUSES & set(c)}
    # 9 x 0.25 GB over a 0.5 GB quota: the six others go, oldest first; the three STOPs stay
    done = enforce(store, 30, 0.5, 0, now)
    left = {i.id for i in IncidentIndex(tmp_path).list()}
    assert left == safety and done.deleted == 6
    assert all((tmp_path / i / "cam0.mp4").is_file() for i in safety)  # clips too
    assert done.blocked and "only safety incidents" in done.blocked and "3 kept" in \
        done.blocked
    # the disk below its floor: recording stops rather than delete a STOP
    with pytest.raises(DiskFloor, match=r"3 safety incidents .* kept, never deleted"):
        enforce(store, 30, 0.5, 1, now, free=lambda _: 0)
    assert {i.id for i in IncidentIndex(tmp_path).list()} == safety
    # a new non-safety incident is the one that goes, however new it is
    _put(store, "new-alert", now, ("alert",), GB // 4)
    assert enforce(store, 30, 0.5, 0, now).deleted == 1
    assert {i.id for i in IncidentIndex(tmp_path).list()} == safety
    # only its age removes a safety incident (retention_days: the operator's choice)
    assert enforce(store, 1 / 86400 * 1800, 1e6, 0, now).deleted == 3
    store.close()


def test_the_issue_31_flood_no_longer_erases_the_real_stop(tmp_path):
    """The real recorder's STOP/latch incident with its clip, then a flood through the
    console (refused credentials and an operator's refused edits), with retention at a limit
    below what they take: the STOP and its clip stay."""
    client = TestClient(build_app(make_console(tmp_path)))
    data_dir = tmp_path / "incidents"
    (stop,) = IncidentIndex(data_dir).list()
    assert {"stop", "latch"} <= set(stop.causes) and stop.clip_paths()
    body = {"camera": "cam0", "kind": "protective", "points_px": BOWTIE}
    for _ in range(150):
        assert client.put("/api/zones/" + "z" * 15_000, json=body).status_code == 401
    for _ in range(10):  # an operator's refused edits are incidents (zone_edit), not safety
        r = client.put("/api/zones/aisle", json=body, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 422
    listed = IncidentIndex(data_dir).list()
    assert len(listed) == 11
    store = IncidentStore(data_dir)
    try:
        quota = (stop.bytes + 1) / GB  # room for the STOP alone
        done = enforce(store, 30, quota, 0, time.time())
    finally:
        store.close()
    (kept,) = IncidentIndex(data_dir).list()
    assert kept.id == stop.id and kept.clip_paths() == stop.clip_paths()
    assert done.deleted == 10 and done.blocked is None


def _step(t: float, seq: int, image: np.ndarray, command: Command, **kw) -> Step:
    info = FrameInfo("cam0", seq, t, image.shape[1], image.shape[0])
    return Step(StepResult(t, command, kw.pop("changed", False), frame=info, **kw),
                Frame(image, info), seq)


def test_the_recorder_keeps_its_stop_over_the_quota_and_alerts_once(tmp_path):
    alerts = []
    recorder = IncidentRecorder(RecorderConfig(enabled=True, pre_s=0.2, post_s=0.2,
                                               max_gb=1e-9, min_free_gb=0.0),
                                tmp_path, ["cam0"], on_alert=alerts.append)
    image = np.full((72, 128, 3), 90, np.uint8)
    run = Command("RUN", 1.0)
    stop = Command("STOP", 0.0, (Reason("protective_zone", "person 0 in zone"),), latched=True)
    try:
        recorder.on_step(_step(0.0, 0, image, run))
        recorder.on_step(_step(0.1, 1, image, stop, changed=True))  # stop, latch
        k, deadline = 2, time.monotonic() + 30.0
        while not alerts and time.monotonic() < deadline:  # the worker finishes the clip
            recorder.on_step(_step(k * 0.1, k, image, stop))
            k += 1
            time.sleep(0.05)
        assert alerts, "no retention_blocked alert within 30 s"
        for j in range(k, k + 40):  # retention runs again: no second alert
            recorder.on_step(_step(j * 0.1, j, image, stop))
        time.sleep(1.2)
        recorder.on_step(_step((k + 40) * 0.1, k + 40, image, stop))
    finally:
        recorder.close(timeout=10.0)
    assert [a.kind for a in alerts] == [BLOCKED_ALERT]
    assert "only safety incidents" in alerts[0].message and recorder.stopped is None
    (kept,) = IncidentIndex(tmp_path).list()
    assert set(kept.causes) == {"stop", "latch"} and kept.complete
    assert json.loads((tmp_path / kept.id / "incident.json").read_text())["id"] == kept.id
