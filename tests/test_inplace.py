"""The in-place detection check through the real driver and pipeline (issue 30): the test
figure pasted into the protective zone of the live frame, matched to its light and noise, must
be found; in a light the model cannot see in it is not, and the cell STOPs naming the zone."""

from __future__ import annotations

import numpy as np
import pytest

from monitor.detector import envelope as env
from monitor.detector.inplace import FAULT_NAME, Figure, InPlaceCheck, covered, paste
from monitor.driver import Driver
from monitor.frames import Frame
from monitor.pipeline import Pipeline
from monitor.policy import STOP, PolicyConfig
from monitor.types import FrameInfo
from monitor.zones.masks import zone_regions_px
from tests.helpers import protective_walk

FPS = 5.0
PERIOD_S = 1.0


@pytest.fixture(scope="module")
def walk():
    scene, cell = protective_walk(FPS)
    return scene, cell, list(scene.frames())


def _drive(detector, walk, condition: dict):
    """The walk through Driver + Pipeline with a timer tick between frames; per frame step:
    (the step's faults, state)."""
    scene, cell, frames = walk
    cam = scene.camera
    zones = {cam.camera_id: [(z.id, p) for z, p in zone_regions_px(cell, cam.camera_id,
                                                                   ("protective",))]}
    check = InPlaceCheck(detector.self_test_case, detector.detect, zones, PERIOD_S)
    driver = Driver(Pipeline(detector, cam.camera_id, PolicyConfig(), cell), inplace=check)
    rows = []
    for k, (img, truth) in enumerate(frames):
        t = truth.time_s
        image = env.degrade(img, rng=np.random.default_rng(k), **condition) if condition \
            else img
        step = driver.step(Frame(image, FrameInfo(cam.camera_id, k, t, cam.width,
                                                  cam.height)), t)
        rows.append((step.result.faults, step.result.command.state))
        driver.step(None, t + 0.5 / FPS)  # the tick between two frames: the check runs here
    return rows, check


def test_a_clean_walk_never_raises_the_in_place_fault(detector, walk):
    rows, check = _drive(detector, walk, {})
    assert check.runs >= 5  # it did run, every second, on the live frames
    assert not [f for faults, _ in rows for f in faults if f.name == FAULT_NAME]


@pytest.mark.parametrize("condition", [{"gain": 0.4}, {"gain": 0.4, "noise": 20.0},
                                       {"gain": 0.22, "noise": 20.0, "blur": 2.0}],
                         ids=["dim", "dim-noise", "dark-noise-blur"])
def test_in_light_the_model_cannot_see_in_the_in_place_check_stops_the_cell(
        detector, walk, condition):
    rows, _ = _drive(detector, walk, condition)
    # from the first check on (the first frame), every step carries the fault and is a STOP
    named = [f for faults, _ in rows for f in faults if f.name == FAULT_NAME]
    assert len(named) == len(rows)
    assert named[0].reason.startswith(
        "cam0 cannot see a person in robot-protective in the current image")
    assert {state for _, state in rows} == {STOP}


def test_paste_matches_the_local_light_and_the_figure_is_where_it_says(detector):
    figure = Figure.from_case(detector.self_test_case)
    frame = np.full((360, 640, 3), 48, np.uint8)
    out, box = paste(frame, figure, (200, 100, 320, 300), np.random.default_rng(0))
    x1, y1, x2, y2 = (round(v) for v in box)
    assert 200 <= x1 < x2 <= 320 and 100 <= y1 < y2 <= 300
    # the figure is as much darker than its test image as the frame is darker than 120 grey
    assert out[y1:y2, x1:x2].max() <= round(245 * 48 / figure.background_mean) + 1
    assert covered(box, np.array([[x1, y1, x2, y2]], np.float32)) == pytest.approx(1.0)
    assert covered(box, np.zeros((0, 4), np.float32)) == 0.0
