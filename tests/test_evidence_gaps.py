"""Bugs a safety assessor applied by hand that no test caught (issue 45), each with the test
that catches it: a foot point just outside a mask counted as visible, another camera's
seen-free map used however old it is, a detector-error frame counted as a seen-free frame for
a lost person's area, and the bus decoder's nesting bound raised above 16. Real components:
the synthetic model, the zone check, the tracker, the policy."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from monitor.config import demo_cell_path
from monitor.detector import Detector, DetectorConfig
from monitor.pipeline import Pipeline
from monitor.pipeline.data import CameraState
from monitor.pipeline.locate import free_elsewhere
from monitor.policy import STOP, PolicyConfig
from monitor.scene import Camera, DemoScene, Figure, draw_figure
from monitor.scene.cell import CellScene, zone_data
from monitor.tracking.tracks import PersonTracker
from monitor.types import FrameInfo
from monitor.wire import payload as pj
from monitor.zones import load_cell, parse_cell
from monitor.zones.visibility import hidden_feet
from tests.helpers import live_frame

# --- masks: a foot point within the mask's margin is hidden ----------------------------------


def test_a_foot_point_just_outside_a_mask_is_hidden_within_the_margin():
    """A mask hides what stands in it, and its edge is uncertain by ``margin_px``: a foot
    point 2 px outside the polygon is as hidden as one inside (a margin of the wrong sign
    made it visible, so a lost person's area was seen free there); 12 px outside is not."""
    mask = np.array([[100, 100], [300, 100], [300, 300], [100, 300]], np.float32)
    points = np.array([[200.0, 200.0], [302.0, 200.0], [200.0, 298.0], [312.0, 200.0]])
    got = hidden_feet(points, (640, 360), None, None, {}, (mask,), mask_margin_px=5.0)
    assert got.tolist() == [True, True, True, False]
    assert hidden_feet(points, (640, 360), None, None, {}, (mask,)).tolist() == \
        [True, False, True, False]


# --- another camera's seen-free map, only while it is fresh ---------------------------------


def _two_cameras():
    scene0 = CellScene((), fps=2.0, duration_s=1.0)
    k = np.array([[450.0, 0, 320], [0, 450.0, 180], [0, 0, 1]])
    cam1 = Camera.look_at("cam1", (640, 360), k, (0.0, 6.5, 3.2), (0.0, 0.0, 0.6))
    data = zone_data(scene0)
    data["cameras"] += zone_data(dataclasses.replace(scene0, camera=cam1))["cameras"]
    cell = parse_cell(data)
    cameras = {cid: CameraState(tracker=PersonTracker(to_floor=cell.camera_models[cid]
                                                      .pixel_to_floor))
               for cid in ("cam0", "cam1")}
    return cell, cameras


def test_another_cameras_seen_free_map_counts_only_while_it_is_fresh():
    """cam1 saw the whole floor free at 0 s and then stopped delivering: at 0.5 s its map
    frees cam0's lost persons' areas, at 1.5 s (older than clear_time, 1 s) it frees nothing
    (used however old it is, a camera that died showing an empty cell freed every hold)."""
    cell, cameras = _two_cameras()
    where = cameras["cam1"].tracker.where
    where.view(640, 360)
    where.update(0.0, np.zeros((0, 4)), True, 0.0, None)  # all seen free at once
    fresh = free_elsewhere(cameras, cell, "cam0", 0.5, 1.0)
    assert fresh is not None and fresh(np.array([[0.0, -1.5], [0.5, 1.0]])).all()
    assert free_elsewhere(cameras, cell, "cam0", 1.5, 1.0) is None
    assert free_elsewhere(cameras, cell, "cam0", 1.0, 1.0) is not None  # exactly clear_time


# --- a detector-error frame sees nothing free -----------------------------------------------


class FailsOn(Detector):
    """The synthetic model, raising on the frames named (an inference that fails: the
    pipeline's own fault path, as a driver or GPU error would take it)."""

    def __init__(self, path, bad: set[int]) -> None:
        super().__init__(path, DetectorConfig(threads=1))
        self.bad = bad

    def detect_timed(self, image, frame, pre_merge=None):
        if frame is not None and frame.seq in self.bad:
            raise RuntimeError("inference failed")
        return super().detect_timed(image, frame, pre_merge=pre_merge)


@pytest.mark.parametrize("errors", [True, False], ids=["errors", "no-errors"])
def test_a_detector_error_frame_is_no_seen_free_frame_for_a_lost_persons_area(
        synthetic_model, errors):
    """A person stands in the protective zone, then is gone from the image (lost in open
    view) at 1.0 s; every other frame until 2.0 s the detector fails. The zone is free only
    once seen free for clear_time (1 s) without a break: from the first frame after the last
    failure (2.0 s) on, so held until 3.0 s; without failures it is free from 2.0 s.
    Counting a failed frame as seen free released it at 2.0 s while nobody had looked."""
    bad = set(range(11, 20, 2)) if errors else set()
    detector = FailsOn(synthetic_model, bad)
    pipe = Pipeline(detector, "cam0", PolicyConfig(restart_interlock="auto"),
                    load_cell(demo_cell_path()))
    scene = DemoScene()
    background = scene.background()
    feet = scene.camera.project(np.array([[0.0, -0.8, 0.0], [0.0, -0.8, 1.75]]))
    person = Figure((float(feet[0][0]), float(feet[0][1])), float(feet[0][1] - feet[1][1]))
    held = {}
    for i in range(32):
        t = i / 10
        img = live_frame(background, i)
        if i < 10:
            draw_figure(img, person)
        res = pipe.process(img, FrameInfo("cam0", i, t, 1280, 720), t)
        held[i] = any(h.lost and h.kind == "protective"
                      for h in (res.zone_report.hits if res.zone_report else ()))
        if i in bad:
            assert res.command.state == STOP and res.zone_report is None
    assert held[10], "the person's area holds the zone once lost"
    # (when it is released is not asserted: this person stands in front of the demo cell's
    # robot base, whose shadow hides a crouching person (issue 44), so the area may stay held
    # until a confirm-clear; what this test guards is that no failed frame released it early)
    if errors:
        assert all(held[i] for i in range(20, 30)), sorted(k for k, v in held.items() if v)
    else:
        assert all(held[i] for i in range(10, 20)), sorted(k for k, v in held.items() if v)


# --- the bus decoder's nesting bound --------------------------------------------------------


@pytest.mark.parametrize("depth", [16, 17, 18, 40])
def test_the_bus_decoder_refuses_the_first_level_past_16(depth):
    """Exactly 16 levels decode; 17 are refused (a bound raised to 128 let a 100-level
    payload through to the JSON parser: the tests only tried hundreds of levels)."""
    for payload in (b"[" * depth + b"]" * depth,
                    b'{"a": ' + b"[" * (depth - 1) + b"]" * (depth - 1) + b"}"):
        if depth <= pj.MAX_DEPTH:
            assert pj.load(payload, 1000) is not None
        else:
            with pytest.raises(pj.PayloadError, match="nested deeper than 16 levels"):
                pj.load(payload, 1000)
    assert pj.MAX_DEPTH == 16


@pytest.mark.parametrize("payload, deepest", [
    pytest.param(b"[" + b"[" * 15 + b"]" * 15 + b"," + b"[" * 15 + b"]" * 15 + b"]", 16,
                 id="two-16-deep-branches"),
    pytest.param(b"[" + b"[]," * 20 + b"[" * 15 + b"]" * 15 + b"]", 16, id="siblings-then-16"),
    pytest.param(b"[" + b"[]," * 20 + b"[" * 16 + b"]" * 16 + b"]", 17, id="siblings-then-17"),
    pytest.param(b"[[[]," + b"[" * 15 + b"]" * 15 + b"]]", 17, id="17-after-a-close"),
])
def test_the_depth_is_the_deepest_nesting_not_the_bracket_count(payload, deepest):
    """More than 16 brackets in all, nested at most 16 deep, decode; 17 deep anywhere (after
    siblings, after a closing bracket) is refused: the scan counts each level once, up and
    down."""
    if deepest <= pj.MAX_DEPTH:
        assert pj.load(payload, 1000) is not None
    else:
        with pytest.raises(pj.PayloadError, match="nested deeper than 16 levels"):
            pj.load(payload, 1000)
