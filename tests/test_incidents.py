"""The incident recorder (monitor/incidents/): a replayed scene with an entry, a refused and an
accepted reset gives incidents whose clips, index rows and export match events.jsonl; a data
dir that cannot be written, a disk below the free-space floor and a locked index stop
recording with an alert while every command stays the same; on_step never waits."""

from __future__ import annotations

import csv
import io
import json
import signal
import sqlite3
import subprocess
import threading
import time
import zipfile
from pathlib import Path

import av
import numpy as np
import pytest

from monitor.config import demo_cell_path, parse_config
from monitor.driver import Step
from monitor.errors import ConfigError
from monitor.frames import Frame
from monitor.incidents import IncidentIndex, RecorderConfig
from monitor.incidents.recorder import MAX_QUEUED_FRAMES, IncidentRecorder
from monitor.incidents.retention import GB, DiskFloor, Retention, enforce
from monitor.incidents.ring import FrameRing, RingFrame
from monitor.incidents.store import IncidentStore
from monitor.incidents.triggers import Triggers
from monitor.pipeline import StepResult
from monitor.policy import Command, Reason, ResetOutcome
from monitor.replay.video import ReplaySettings, replay
from monitor.scene import DemoScene, write_video
from monitor.types import Alert, Fault, FrameInfo
from monitor.zones import load_cell
from tests.helpers import run_monitor
from tests.processes import one_inference_thread
from tests.shared import built_once

PRE_S, POST_S, TICK_S = 1.5, 1.0, 0.05
# walks into the protective zone (~0.8 s), stands there, leaves the view by ~4.5 s
PATH = ((0.0, -2.6, -0.3), (1.2, -0.4, -0.3), (2.6, -0.4, -0.3), (4.5, -6.5, -0.3),
        (8.0, -6.5, -0.3))
RESETS = (2.0, 6.6)  # refused (the person is inside), accepted (gone for > clear_time)


def _replay_recording(base: Path, model: Path
                      ) -> tuple[Path, list[dict], subprocess.CompletedProcess]:
    """`monitor replay --incidents DIR` as a user runs it, with a short [recorder] window."""
    video = base / "walk-in-out.mp4"
    scene = DemoScene(fps=5.0, duration_s=8.0, path=PATH)
    write_video(video, scene.frames(), scene.fps)
    config = base / "monitor.toml"
    config.write_text(one_inference_thread(
        f"[recorder]\nenabled = true\npre_s = {PRE_S}\npost_s = {POST_S}\n"))
    proc = run_monitor("replay", video, "--zones", demo_cell_path(), "--model",
                       model, "--config", config, "--out", base / "out",
                       "--incidents", base / "incidents", "--no-video",
                       "--reset-at", ",".join(map(str, RESETS)), timeout=600)
    assert proc.returncode == 0, proc.stderr
    events = [json.loads(line) for line in (base / "out/events.jsonl").read_text().splitlines()]
    return base / "incidents", events, proc


@pytest.fixture(scope="module")
def recorded(synthetic_model, tmp_path_factory):
    """The recorded incidents, built once for both test workers (their tests only read them)."""
    return built_once(tmp_path_factory, "incidents-recorded",
                      lambda base: _replay_recording(base, synthetic_model))


def _causes(event: dict) -> set[str]:
    return {r["code"] for r in event["reasons"]} - {"startup", "clearing", "latched"}


@pytest.mark.slow
def test_entry_refused_and_accepted_reset_are_incidents_matching_the_events(recorded):
    data_dir, events, proc = recorded
    incidents = sorted(IncidentIndex(data_dir).list(), key=lambda i: i.time_s)
    assert [i.causes for i in incidents] == [("stop", "latch"), ("reset_refused", "alert"),
                                             ("reset_accepted", "alert")]
    assert all(i.complete for i in incidents)
    stop = next(e for e in events if e["type"] == "command" and _causes(e))
    assert incidents[0].time_s == stop["time_s"] and incidents[0].state == "STOP"
    resets = [e for e in events if e["type"] == "command" and "reset" in e]
    for incident, event in zip(incidents[1:], resets, strict=True):
        assert incident.time_s == event["time_s"]
        assert incident.operator == event["reset"]["operator"] == "replay"
        assert incident.reset_accepted == event["reset"]["accepted"]
        assert incident.reset_message == event["reset"]["message"]
        assert incident.record["command"] == event
    assert not incidents[1].reset_accepted and "protective" in incidents[1].reset_message
    assert incidents[2].reset_accepted
    zones_hash = load_cell(demo_cell_path()).config_hash
    for incident in incidents:
        assert incident.zones_hash == zones_hash
        assert incident.config_hash.startswith("sha256:")
        # its events are exactly the run's events of its window, in order
        t = incident.time_s
        mine = incident.record["events"]
        window = [e for e in events if t - PRE_S <= e["time_s"] <= t + POST_S]
        assert all(e in mine for e in window)
        assert all(t - PRE_S <= e["time_s"] <= t + POST_S + TICK_S + 1e-6 for e in mine)
        first = events.index(mine[0])
        assert events[first:first + len(mine)] == mine
        assert incident.record["commands"] == [e for e in mine if e["type"] == "command"]
    assert "incidents          3 in" in proc.stdout


@pytest.mark.slow
def test_clips_decode_as_h264_with_frames_from_before_the_stop(recorded):
    data_dir, _, _ = recorded
    for incident in IncidentIndex(data_dir).list():
        clip = incident.record["clips"]["cam0"]
        path = IncidentIndex(data_dir).clip_path(incident.id)
        assert path == incident.dir / "cam0.mp4" and path.is_file()
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            assert stream.codec_context.name == "h264"
            frames = [f for f in container.decode(stream)]
        assert len(frames) == clip["frames"] > clip["frames_before"] > 0
        times = [float(f.pts * f.time_base) for f in frames]
        # from pre_s before the event to post_s after it, at the video's 5 fps
        assert times[-1] - times[0] == pytest.approx(clip["last_s"] - clip["first_s"],
                                                     abs=0.01)
        earliest = max(-PRE_S, -incident.time_s)  # the video starts 0.8 s before the STOP
        assert earliest - 1e-6 <= clip["first_s"] < earliest + 0.2 + 1e-6
        assert clip["frames_before"] == sum(1 for x in times if x <= times[0] - clip["first_s"]
                                            + 1e-3)
        image = frames[0].to_ndarray(format="bgr24")
        assert image.shape == (720, 1280, 3) and image.std() > 10  # a picture, not blank


@pytest.mark.slow
def test_export_csv_json_and_zip_match_the_index(recorded, tmp_path):
    data_dir, _, _ = recorded
    rows = [i.row() for i in IncidentIndex(data_dir).list()]
    proc = run_monitor("incidents", "export", "--dir", data_dir, "--format", "csv")
    assert proc.returncode == 0, proc.stderr
    exported = list(csv.DictReader(io.StringIO(proc.stdout)))
    assert [r["id"] for r in exported] == [r["id"] for r in rows]
    assert [r["causes"] for r in exported] == [r["causes"] for r in rows]
    assert [r["operator"] for r in exported] == [r["operator"] or "" for r in rows]
    proc = run_monitor("incidents", "export", "--dir", data_dir, "--format", "json")
    assert [r["record"]["events"] for r in json.loads(proc.stdout)] == \
        [i.record["events"] for i in IncidentIndex(data_dir).list()]
    out = tmp_path / "incidents.zip"
    proc = run_monitor("incidents", "export", "--dir", data_dir, "--format", "zip", "--out", out)
    assert proc.returncode == 0, proc.stderr
    with zipfile.ZipFile(out) as z:
        names = set(z.namelist())
        for row in rows:
            assert f"{row['id']}/cam0.mp4" in names and f"{row['id']}/incident.json" in names
            assert z.read(f"{row['id']}/cam0.mp4") == \
                (data_dir / row["id"] / "cam0.mp4").read_bytes()
    listed = run_monitor("incidents", "list", "--dir", data_dir, "--cause", "reset_refused")
    assert listed.returncode == 0 and len(listed.stdout.splitlines()) == 1
    assert "reset by replay: refused" in listed.stdout


# --- failures of the data dir: recording stops with an alert, the commands stay the same ------

def _commands(results: list[StepResult]) -> list[dict]:
    return [{**r.command.to_dict(), "now": r.now} for r in results]


@pytest.fixture(scope="module")
def short_video(tmp_path_factory) -> Path:
    video = tmp_path_factory.mktemp("short") / "walk-in.mp4"
    scene = DemoScene(fps=5.0, duration_s=2.4,
                      path=((0.0, -2.6, -0.3), (1.2, -0.4, -0.3), (9.0, -0.4, -0.3)))
    write_video(video, scene.frames(), scene.fps)
    return video


@pytest.fixture(scope="module")
def baseline(short_video, detector, tmp_path_factory):
    results: list[StepResult] = []
    settings = ReplaySettings(out_dir=tmp_path_factory.mktemp("base"), annotate=False,
                              progress=False)
    replay(short_video, detector, load_cell(demo_cell_path()), settings,
           publish=results.append)
    assert any(r.command.latched for r in results)  # the scene has a STOP to record
    return _commands(results)


def _file_in_the_way(tmp: Path) -> tuple[Path, dict]:
    (tmp / "data").write_text("a file where the data directory should be")
    return tmp / "data" / "incidents", {}


def _disk_below_floor(tmp: Path) -> tuple[Path, dict]:
    return tmp / "incidents", {"min_free_gb": 1e9}  # more than any disk has free


def _index_locked(tmp: Path) -> tuple[Path, dict]:
    IncidentStore(tmp / "incidents").close()  # an index in WAL mode, then locked below
    return tmp / "incidents", {"sqlite_timeout_s": 0.2}


@pytest.mark.parametrize("failure", [_file_in_the_way, _disk_below_floor, _index_locked])
def test_a_data_dir_that_cannot_be_written_stops_recording_with_an_alert_only(
        failure, short_video, detector, baseline, tmp_path):
    data_dir, options = failure(tmp_path)
    lock = None
    if failure is _index_locked:
        lock = sqlite3.connect(str(data_dir / "index.sqlite3"), isolation_level=None)
        lock.execute("BEGIN EXCLUSIVE")  # another process holding the index
    results: list[StepResult] = []
    settings = ReplaySettings(out_dir=tmp_path / "out", annotate=False, progress=False,
                              incidents_dir=data_dir,
                              recorder=RecorderConfig(enabled=True, **options))
    try:
        summary = replay(short_video, detector, load_cell(demo_cell_path()), settings,
                         publish=results.append)
    finally:
        if lock is not None:
            lock.execute("ROLLBACK")
            lock.close()
    assert _commands(results) == baseline  # the safety loop decided exactly the same
    assert summary.incidents["stopped"] and not summary.incidents["recording"]
    alerts = [json.loads(line) for line in (tmp_path / "out/events.jsonl").read_text()
              .splitlines()]
    stopped = [a for a in alerts if a.get("kind") == "recorder_stopped"]
    assert len(stopped) == 1 and "the monitor goes on commanding" in stopped[0]["message"]
    if failure is _disk_below_floor:
        assert "below the floor of min_free_gb" in stopped[0]["message"]
    if failure is _index_locked:
        assert "locked" in stopped[0]["message"]


# --- the safety loop's side never waits ------------------------------------------------------

def _step(t: float, seq: int, image: np.ndarray, command: Command, **kw) -> Step:
    info = FrameInfo("cam0", seq, t, image.shape[1], image.shape[0])
    return Step(StepResult(t, command, kw.pop("changed", False), frame=info, **kw),
                Frame(image, info), seq)


def test_on_step_never_waits_for_a_stuck_recorder(tmp_path):
    """The worker stuck on a locked index (30 s busy timeout): on_step still returns at once
    for every step and drops the frames it cannot queue, counting them."""
    IncidentStore(tmp_path).close()
    lock = sqlite3.connect(str(tmp_path / "index.sqlite3"), isolation_level=None)
    lock.execute("BEGIN EXCLUSIVE")
    recorder = IncidentRecorder(RecorderConfig(enabled=True, sqlite_timeout_s=30.0,
                                               max_fps=60.0), tmp_path, ["cam0"])
    image = np.full((72, 128, 3), 90, np.uint8)
    stop = Command("STOP", 0.0, (Reason("protective_zone", "person 0 in zone"),), latched=True)
    done = threading.Event()

    def loop() -> None:
        recorder.on_step(_step(0.0, 0, image, stop, changed=True))  # an incident: the put hangs
        for k in range(1, 200):
            recorder.on_step(_step(k / 50, k, image, stop))
        done.set()

    try:
        threading.Thread(target=loop, daemon=True).start()
        assert done.wait(20.0), "on_step waited for the recorder"
        assert recorder.dropped_frames >= 199 - MAX_QUEUED_FRAMES - 1
        assert recorder.stopped is None  # still waiting on the lock, not failed
    finally:
        lock.execute("ROLLBACK")
        lock.close()
        recorder.close(timeout=5.0)


# --- pieces --------------------------------------------------------------------------------

def test_triggers_each_cause_once_and_a_flickering_fault_once():
    run, stop = Command("RUN", 1.0), Command("STOP", 0.0, (Reason("fault", "camera lost"),))
    latched = Command("STOP", 0.0, (Reason("protective_zone", "p"),), latched=True)
    refused = Command("STOP", 0.0, (Reason("protective_zone", "p"),), latched=True,
                      reset=ResetOutcome("anna", False, "refused: person 0 in zone"))
    lost = Fault("camera_lost", "gone", True, "cam1")
    alert = Alert("scene_change", "warning", "shelf moved", "cam0", 0.0)
    trig = Triggers()
    seq = [(0.0, Command("STOP", 0.0, (Reason("startup", "s"),)), (), ()),
           (1.0, run, (), ()), (2.0, stop, (lost,), ()), (2.1, stop, (), ()),
           (2.2, stop, (lost,), ()), (3.0, run, (), ()), (4.0, latched, (), (alert,)),
           (5.0, refused, (), ())]
    got = [trig.update(StepResult(t, c, False, faults=f, alerts=a)) for t, c, f, a in seq]
    assert got == [(), (), ("stop", "fault"), (), (), (), ("stop", "latch", "alert"),
                   ("reset_refused",)]


def test_ring_keeps_the_window_and_the_byte_budget():
    ring = FrameRing(window_s=2.0, budget_bytes=10_000)
    for k in range(50):
        ring.push(RingFrame(k * 0.1, bytes(300), None))
    assert ring.frames[0].time == pytest.approx(4.9 - 2.0)
    for k in range(50, 100):
        ring.push(RingFrame(k * 0.1, bytes(1000), None))
    assert ring.bytes <= 10_000 and len(ring) == 10 and ring.evicted_for_budget > 0


def _record(incident_id: str, wall: float, causes: tuple[str, ...] = ("alert",)) -> dict:
    return {"id": incident_id, "wall": wall, "time_s": 0.0, "cell": "c",
            "causes": list(causes), "state": "STOP", "latched": True, "describe": "STOP",
            "reset": None, "zones_hash": "z", "config_hash": "c"}


def test_retention_by_age_size_and_free_space_oldest_first(tmp_path):
    """Non-safety incidents (alerts here): tests/test_incident_retention.py has the rest."""
    store = IncidentStore(tmp_path)
    now = time.time()
    for k, age_days in enumerate((40, 20, 10, 5, 1)):
        (tmp_path / f"i{k}").mkdir()
        store.put(_record(f"i{k}", now - age_days * 86400), size=GB // 2, complete=True)
    assert enforce(store, 30, 1e6, 0, now).deleted == 1  # 40 days old
    # 2 GB left > 1.2 GB: the two oldest
    assert enforce(store, 30, 1.2, 0, now) == Retention(deleted=2)
    assert [i.id for i in IncidentIndex(tmp_path).list()] == ["i4", "i3"]
    assert not (tmp_path / "i0").exists() and (tmp_path / "i4").is_dir()
    free = iter([0, 0, 10 * GB])  # below the floor until the two left are gone
    assert enforce(store, 30, 1e6, 1, now, free=lambda _: next(free)).deleted == 2
    with pytest.raises(DiskFloor, match="below the floor"):
        enforce(store, 30, 1e6, 1, now, free=lambda _: 0)
    store.close()


def test_recorder_section_of_the_config_is_validated():
    config = parse_config({"recorder": {"enabled": True, "pre_s": 4.0}}, "m.toml")
    assert config.recorder.enabled and config.recorder.pre_s == 4.0
    with pytest.raises(ConfigError, match=r"m.toml: \[recorder\] pre_s: should be greater"):
        parse_config({"recorder": {"pre_s": -1.0}}, "m.toml")
    with pytest.raises(ConfigError, match=r"\[recorder\] unknown key 'pre'"):
        parse_config({"recorder": {"pre": 1.0}}, "m.toml")


# --- in the service: the queryable, the counters, the clip ------------------------------------

@pytest.mark.slow
def test_the_service_records_the_demo_stop_and_answers_the_incidents_query(
        tmp_path, synthetic_model):
    import urllib.request

    from tests.processes import Service, codes, wait_for

    # a short clip: the recorder runs at low priority and a loaded machine starves it
    # loose frame limits, as in tests/test_handover_cells.py: at a load of 8 the default 0.5 s
    # latched a STOP for a stall again and again, and the demo's entry fell inside it (this
    # test is about recording, not frame age: tests/test_stall.py)
    extra = ('[recorder]\nenabled = true\ndata_dir = "incidents"\npre_s = 1.0\npost_s = 0.5\n'
             '[policy]\nframe_timeout = 3.0\nmax_frame_age = 3.0\n')
    with Service(tmp_path, synthetic_model, "synthetic:demo", extra) as svc:
        svc.next_command(0, lambda c: "protective_zone" in codes(c), 60, "the demo's STOP")

        def incidents() -> list[dict]:
            replies = list(svc.session.get("workcell/t5/safety/incidents?cause=stop",
                                           timeout=3.0))
            body = json.loads(replies[0].ok.payload.to_bytes())
            assert body["schema"] == "workcell.safety.incidents/1" and body["cell"] == "t5"
            return [r for r in body["incidents"] if r["complete"]]

        # the recorder works at low priority: on a loaded machine its clip takes a while. The
        # demo's STOP for its protective zone: a loaded host may have latched a STOP for a
        # stall first (an incident too, with no frames before it: the stall discards them),
        # and a person entering during that STOP opens no new incident; so the latch is reset
        # as an operator would, and the demo's looped walk enters again
        sent: set[str] = set()

        def protective() -> list[dict]:
            rows = [r for r in incidents() if "protective" in r["describe"]]
            if not rows:
                svc.release_latch(sent)
            return rows

        rows = wait_for(protective, 150, "a complete STOP incident for the protective zone",
                        svc)
        url = f"http://127.0.0.1:{svc.metrics_port}/metrics"
        def metrics() -> str | None:
            text = urllib.request.urlopen(url, timeout=3).read().decode()
            return text if 'monitor_incidents_total{cause="stop"}' in text else None

        text = wait_for(metrics, 30, "the incident counter", svc)
        assert "monitor_recorder_recording 1.0" in text
        # 0, or 143 when a loaded machine made it overrun its shutdown grace (exits anyway)
        assert svc.stop(signal.SIGTERM) in (0, 128 + signal.SIGTERM)
    assert "stop" in rows[0]["causes"].split(",") and rows[0]["state"] == "STOP"
    clip = IncidentIndex(tmp_path / "incidents").clip_path(rows[0]["id"])
    with av.open(str(clip)) as container:
        frames = list(container.decode(container.streams.video[0]))
    record = IncidentIndex(tmp_path / "incidents").get(rows[0]["id"]).record
    assert len(frames) == record["clips"]["cam0"]["frames"] > \
        record["clips"]["cam0"]["frames_before"] > 0
