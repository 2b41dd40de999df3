"""The lost persons' areas on screen (issue 46): the real pipeline (synthetic model, zone check,
tracker) on a generated scene where a person hides behind a cabinet in the protective zone;
the step hands on where they could be (``StepResult.areas``) and what the camera cannot see
(``StepResult.unseen``), and the annotated frame shows them, in the area's colour where the
area is and nowhere else."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from monitor.pipeline import Pipeline
from monitor.pipeline.area_views import cell_mask_px, outlines_px
from monitor.policy import PolicyConfig
from monitor.records.annotate import annotate
from monitor.records.areas_draw import AREA_ALPHA, AREA_BGR, UNSEEN_BGR
from monitor.replay import scenarios as sc
from monitor.types import FrameInfo
from monitor.zones import parse_cell

EVIDENCE = {s.name: s for s in sc.evidence_scenarios()}


@pytest.fixture(scope="module")
def hidden_step(synthetic_model):
    """The first step of "stranger-2fps" at which the hidden person's area reaches behind
    the cabinet (and holds the protective zone), with its frame and cell."""
    from monitor.detector import Detector, DetectorConfig

    scenario = EVIDENCE["stranger-2fps"]
    cell = parse_cell(scenario.zone_data())
    cam = scenario.scene.camera
    pipe = Pipeline(Detector(synthetic_model, DetectorConfig(threads=1)), cam.camera_id,
                    PolicyConfig(), cell)
    for k, (img, truth) in enumerate(scenario.scene.frames()):
        t = truth.time_s
        res = pipe.process(img, FrameInfo(cam.camera_id, k, t, cam.width, cam.height), t)
        held = [a for a in res.areas if a.zones and a.hidden.any()]
        if held:
            return res, img, cell, cam.camera_id, held[0]
    raise AssertionError("no area reached behind the cabinet")


def test_a_step_hands_on_the_hidden_persons_area_and_what_the_camera_cannot_see(hidden_step):
    res, img, _cell, camera, area = hidden_step
    assert area.camera_id == camera and "robot-protective" in area.zones
    assert area.regions == ("cabinet",) and not area.waiting_ends
    (unseen,) = res.unseen
    assert unseen.camera_id == camera and unseen.cells.any()
    assert not (area.hidden & ~unseen.cells).any()  # hidden: cells the camera cannot see
    h, w = img.shape[:2]
    assert area.frame_size == (w, h)
    # the outline encloses the area's cells (the console draws it)
    (poly, *_) = outlines_px(area.cells, area.cell_px)
    ys, xs = np.nonzero(area.cells)
    j, i = ys[len(ys) // 2], xs[len(xs) // 2]
    centre = ((i + 0.5) * area.cell_px, (j + 0.5) * area.cell_px)
    assert cv2.pointPolygonTest(np.array(poly, np.float32), centre, False) >= 0


def test_the_annotated_frame_shows_the_area_in_its_colour_where_it_is_and_nowhere_else(
        hidden_step):
    res, img, cell, camera, area = hidden_step
    # the same step with the area emptied (the key of the colours stays, the labels in place;
    # the cabinet's pocket is drawn over the area: tests/test_pockets_on_screen.py)
    nothing = np.zeros_like(area.cells)
    res = replace(res, pockets=())
    bare = replace(res, areas=(replace(area, cells=nothing, hidden=nothing),), unseen=())
    grey = np.full_like(img, 100)  # a plain picture: every colour change is the drawing
    plain, _ = annotate(grey, bare, cell, camera, [])
    drawn, said = annotate(grey, replace(res, areas=(area,), unseen=()), cell, camera, [])
    h, w = grey.shape[:2]
    inside = cell_mask_px(area.cells, area.cell_px, area.frame_size, (w, h))
    # inside, away from the outline: the picture blended with the area's colour
    core = cv2.erode(inside.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    expect = (plain[core].astype(np.float32) * (1 - AREA_ALPHA)
              + np.array(AREA_BGR, np.float32) * AREA_ALPHA).astype(np.uint8)
    assert core.sum() > 100
    assert np.abs(drawn[core].astype(int) - expect.astype(int)).max() <= 1
    # elsewhere (beyond the outline, and the label above the area): nothing changed
    near = cv2.dilate(inside.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    ys, _xs = np.nonzero(inside)
    near[max(0, ys.min() - 40):ys.min(), :] = True  # the label's band
    changed = np.any(drawn != plain, axis=2)
    assert changed[inside].mean() > 0.9
    assert not changed[~near].any()
    assert any("person" in t and "behind cabinet" in t and "robot-protective" in t
               for t in said.areas), said.areas


def test_the_annotated_frame_hatches_what_the_camera_cannot_see(hidden_step):
    res, img, cell, camera, _ = hidden_step
    res = replace(res, pockets=())  # (the pocket's outline: tests/test_pockets_on_screen.py)
    grey = np.full_like(img, 100)
    (unseen,) = res.unseen
    drawn, _ = annotate(grey, replace(res, areas=()), cell, camera, [])
    emptied = replace(unseen, cells=np.zeros_like(unseen.cells))  # the key stays in place
    plain, _ = annotate(grey, replace(res, areas=(), unseen=(emptied,)), cell, camera, [])
    purple = np.all(drawn == UNSEEN_BGR, axis=2) & ~np.all(plain == UNSEEN_BGR, axis=2)
    h, w = grey.shape[:2]
    where = cell_mask_px(unseen.cells, unseen.cell_px, unseen.frame_size, (w, h))
    assert purple.sum() > 50
    grown = cv2.dilate(where.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert not (purple & ~grown).any()


def test_the_consoles_live_payload_carries_the_areas_and_its_view_draws_them(hidden_step,
                                                                             tmp_path):
    """The detections message of the step (as the service publishes it) carries the area; the
    console's state lists it (person, zones, the unseen region, waiting does not end it) and
    its drawn view fills it, and a message without areas draws none."""
    import json

    import yaml

    from monitor.bus.session import detections_body
    from monitor.console.live import LiveRenderer, LiveState
    from monitor.pipeline.area_views import areas_body
    from monitor.zones import load_cell

    res, _, _, camera, area = hidden_step
    zones = tmp_path / "cell.yaml"
    zones.write_text(yaml.safe_dump(EVIDENCE["stranger-2fps"].zone_data()))
    views = {}
    for name, body in (("areas", areas_body(res.areas, res.unseen, camera)), ("none", {})):
        live = LiveState(clock=lambda: 0.0, require_signed=False)  # fresh whatever the load
        persons = replace(res.persons, frame=res.frame)  # as the service's frame carries it
        live.on_detections(json.dumps({**detections_body(persons, res.zone_report),
                                       **body}).encode())
        renderer = LiveRenderer(live, lambda: load_cell(zones), {}, min_render_s=0.0)
        views[name] = cv2.imdecode(np.frombuffer(renderer.jpeg(camera), np.uint8),
                                   cv2.IMREAD_COLOR).astype(int)
        state = live.state()
        assert camera in state["areas"], (state, persons.frame)
        listed = state["areas"][camera]
        if name == "none":
            assert listed == []
            continue
        mine = next(a for a in listed if a["person"] == str(area.who) or
                    a["person"] == area.who)
        assert "robot-protective" in mine["zones"] and mine["regions"] == ["cabinet"]
        assert mine["waiting_ends"] is False
    h, w = views["none"].shape[:2]
    inside = cell_mask_px(area.cells, area.cell_px, area.frame_size, (w, h))
    core = cv2.erode(inside.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    # yellow (BGR 0, 230, 255) over the picture: red and green up, blue down
    gain = (views["areas"][core] - views["none"][core]).mean(axis=0)
    assert gain[2] > 40 and gain[1] > 40 and gain[0] < 0, gain
    far = ~cv2.dilate(inside.astype(np.uint8), np.ones((25, 25), np.uint8)).astype(bool)
    far &= ~cell_mask_px(res.unseen[0].cells, area.cell_px, area.frame_size, (w, h))
    assert np.abs(views["areas"][far] - views["none"][far]).mean() < 1.0


def test_the_docs_picture_of_a_held_cell(hidden_step, tmp_path):
    """docs/tracking.md's picture: the hidden person's area and the unseen floor on the
    annotated frame (written to docs/occlusion/ with UPDATE_DOC_SHOTS=1, else to tmp)."""
    import os
    from pathlib import Path

    res, img, cell, camera, _ = hidden_step
    drawn, said = annotate(img, res, cell, camera, [])
    folder = Path(__file__).resolve().parents[1] / "docs" / "occlusion" \
        if os.environ.get("UPDATE_DOC_SHOTS") == "1" else tmp_path
    assert cv2.imwrite(str(folder / "lost-area.png"), drawn)
    assert said.areas


@pytest.mark.slow
def test_monitor_replays_annotated_video_shows_the_hidden_persons_area(detector, tmp_path):
    """The replay (as `monitor replay` and `monitor demo` run it) of the cabinet scene written
    to a video: in annotated.mp4, at a frame whose step holds the zone for the person behind
    the cabinet, the area's pixels are yellowed against the video's own frame."""
    from monitor.replay.video import ReplaySettings, replay
    from monitor.scene import write_video

    scenario = EVIDENCE["stranger-2fps"]
    video = tmp_path / "cabinet.mp4"
    write_video(video, scenario.scene.frames(), scenario.scene.fps)
    results = []
    out = tmp_path / "out"
    replay(video, detector, parse_cell(scenario.zone_data()),
           ReplaySettings(out_dir=out, progress=False), publish=results.append)
    steps = [r for r in results if r.frame is not None]
    k, res = next((k, r) for k, r in enumerate(steps)
                  if any(a.zones and a.hidden.any() for a in r.areas))
    area = next(a for a in res.areas if a.zones and a.hidden.any())
    cap = cv2.VideoCapture(str(out / "annotated.mp4"))
    for _ in range(k + 1):
        ok, shown = cap.read()
        assert ok
    cap.release()
    raw = cv2.VideoCapture(str(video))
    for _ in range(k + 1):
        ok, plain = raw.read()
        assert ok
    raw.release()
    h, w = shown.shape[:2]
    inside = cell_mask_px(area.cells, area.cell_px, area.frame_size, (w, h))
    core = cv2.erode(inside.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    gain = (shown[core].astype(int) - plain[core].astype(int)).mean(axis=0)
    # yellow (BGR 0, 230, 255) blended in: green and red up, blue down
    assert gain[1] > 20 and gain[2] > 20 and gain[0] < 0, gain
