"""Several cameras sharing the detector: frames ready together run as one batch, and give the
same persons, track ids and commands as running them one after the other (real synthetic
model, generated frames, the demo cell's masks and zones on three cameras)."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest
import yaml

from monitor.config import demo_cell_path
from monitor.detector import Detector
from monitor.driver import Driver, Step, StepInputs
from monitor.frames import Frame
from monitor.pipeline import Pipeline, StepResult
from monitor.policy import PolicyConfig
from monitor.scene import DemoScene
from monitor.types import FrameInfo
from monitor.zones import load_cell
from tests.onnx_models import PERSONS, const_model, cxcywh, to_input

CAMERAS = ("cam0", "cam1", "cam2")
POLICY = PolicyConfig(clear_time=0.3, restart_interlock="auto")
FPS = 10.0


def cell_with_cameras(tmp: Path, ids=CAMERAS) -> Path:
    """The demo cell seen by several cameras with the demo camera's calibration."""
    data = yaml.safe_load(demo_cell_path().read_text())
    data["cameras"] = [dict(data["cameras"][0], id=cid) for cid in ids]
    zones = []
    for zone in data["zones"]:  # image zones (and masks) for every camera: the same view
        if zone.get("camera") == "cam0":
            zones += [dict(zone, camera=cid, id=zone["id"].replace("cam0", cid) + "-" + cid)
                      for cid in ids]
        else:
            zones.append(zone)
    data["zones"] = zones
    path = tmp / "cell.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def rounds() -> list[list[tuple[np.ndarray, FrameInfo]]]:
    """8 rounds; camera k shows the demo walk 4 s later than camera k-1, so the persons
    differ: outside, in the warning zone, in the protective zone (and the masked poster)."""
    scene = DemoScene(fps=FPS, duration_s=14.0)
    images = [image for image, _ in scene.frames()]
    out = []
    for r in range(8):
        out.append([(images[(20 + 10 * r + 40 * k) % len(images)],
                     FrameInfo(cid, r, r / FPS, 1280, 720)) for k, cid in enumerate(CAMERAS)])
    return out


def same(a: StepResult, b: StepResult) -> None:
    assert a.frame == b.frame
    np.testing.assert_allclose(a.persons.boxes_px, b.persons.boxes_px, atol=1e-3)
    np.testing.assert_allclose(a.persons.scores, b.persons.scores, atol=1e-5)
    assert a.track_ids == b.track_ids and a.masked_boxes == b.masked_boxes
    assert {(h.zone_id, h.person) for h in a.zone_report.hits} == \
        {(h.zone_id, h.person) for h in b.zone_report.hits}
    assert a.command.state == b.command.state and a.command.latched == b.command.latched
    assert [r.code for r in a.command.reasons] == [r.code for r in b.command.reasons]


def test_batched_and_one_by_one_give_the_same_persons_and_commands(tmp_path, detector, rounds):
    assert detector.batchable  # the synthetic model has a dynamic batch dimension
    cell = load_cell(cell_with_cameras(tmp_path))
    batched = Pipeline(detector, CAMERAS, POLICY, cell)
    in_turn = Pipeline(detector, CAMERAS, POLICY, cell)
    states, hits = set(), set()
    for frames in rounds:
        now = frames[0][1].capture_time + 0.02
        got = batched.process_batch(frames, now)
        want = [in_turn.process(image, info, now) for image, info in frames]
        assert len(got) == len(want) == len(CAMERAS)
        for a, b in zip(got, want, strict=True):
            same(a, b)
            states.add(a.command.state)
            hits |= {h.kind for h in a.zone_report.hits}
    # the scene really exercised persons in zones and decisions (not an empty comparison)
    assert {"protective", "warning"} <= hits and "STOP" in states


def test_a_model_without_a_batch_dimension_runs_the_frames_in_turn(tmp_path):
    rows = np.zeros((1, 20, 8), np.float32)
    for i, box in enumerate(PERSONS):
        rows[0, i] = [*cxcywh(to_input(box)), 0.9, 0.95, 0.1, 0.0]
    model = const_model(tmp_path / "fixed.onnx", {"output0": rows})  # input [1, 3, 320, 320]
    detector = Detector(model)
    assert not detector.batchable
    pipe = Pipeline(detector, ("a", "b"), POLICY)
    image = np.full((480, 640, 3), 90, np.uint8)
    results = pipe.process_batch([(image, FrameInfo("a", 0, 0.0, 640, 480)),
                                  (image, FrameInfo("b", 0, 0.0, 640, 480))], 0.01)
    for r in results:  # each frame decoded on its own: both persons, in frame pixels
        np.testing.assert_allclose(np.sort(r.persons.boxes_px, axis=0),
                                   np.sort(PERSONS, axis=0), atol=1.0)


class ListFeed:
    """Rounds of frames for ``Driver.run(batch=True)``; cam2 falls silent after round 3."""

    def __init__(self, rounds, silent_after: int) -> None:
        self.items = []
        for r, frames in enumerate(rounds):
            ready = [Frame(image, info) for image, info in frames
                     if info.camera_id != "cam2" or r <= silent_after]
            self.items.append((ready, frames[0][1].capture_time + 0.02))

    def next_batch(self, idle: bool = False):
        return self.items.pop(0) if self.items else None

    def inputs(self, now: float) -> StepInputs:
        return StepInputs()


class Recorder:
    def __init__(self) -> None:
        self.steps: list[Step] = []

    def on_step(self, step: Step) -> None:
        self.steps.append(step)

    def close(self) -> None:
        pass


def test_the_driver_emits_every_cameras_step_and_a_silent_camera_stops_the_cell(tmp_path,
                                                                                 detector,
                                                                                 rounds):
    cell = load_cell(cell_with_cameras(tmp_path))
    policy = PolicyConfig(clear_time=0.3, restart_interlock="auto", max_frame_age=0.25)
    recorder = Recorder()
    driver = Driver(Pipeline(detector, CAMERAS, policy, cell), [recorder])
    driver.run(ListFeed(rounds, silent_after=3), threading.Event(), batch=True)
    seen = [(s.result.frame.camera_id, s.result.frame.seq) for s in recorder.steps]
    # rounds 0-3: three steps each, in camera order; then only cam0 and cam1
    assert seen[:12] == [(c, r) for r in range(4) for c in CAMERAS]
    assert seen[12:] == [(c, r) for r in range(4, 8) for c in ("cam0", "cam1")]
    last = recorder.steps[-1].result.command
    stale = [r for r in last.reasons if r.code == "frame_stale"]
    assert last.state == "STOP" and stale and stale[0].source == "cam2"
