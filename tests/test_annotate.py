"""The replay's annotated video (monitor/records/annotate.py): labels that never overlap, one colour
per zone kind in the preview and the video, and a replay of a generated walk whose frames show the
header, the tracker's person ids, the refused reset and the floor range behind each hit."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from monitor.config import demo_cell_path
from monitor.health import WATCH_BGR, HealthReport, draw_health
from monitor.pipeline import StepResult
from monitor.policy import STOP
from monitor.records.annotate import HEADER_PX, HOLD_S, Annotator, Drawn
from monitor.replay.video import ReplaySettings, replay
from monitor.scene import DemoScene, write_video
from monitor.zones import parse_cell, watch_regions
from monitor.zones.draw import (
    COLOURS_BGR,
    LEGEND_KINDS,
    LEGEND_TOP_PX,
    ZoneDrawCache,
    draw_zones,
    draw_zones_labelled,
    legend_rect,
)
from monitor.zones.labels import intersects, place_labels
from tests.test_floors import demo_data, with_platform
from tests.test_moving_zones import cell_with, cylinder, following, pose
from tests.test_occlusion import with_bench

# --- label placement (pure) -----------------------------------------------------------------


def _no_two_intersect(rects) -> None:
    for a, b in itertools.combinations(rects, 2):
        assert not intersects(a, b), (a, b)


def test_labels_at_the_same_spot_are_moved_apart_and_the_first_keeps_its_place():
    anchors = [(100.0, 50.0)] * 8 + [(104.0, 52.0)] * 4  # twelve labels wanting one place
    sizes = [(90, 18)] * 6 + [(140, 18)] * 6
    reserved = [(0, 0, 640, 28), (500, 30, 636, 110)]  # a header band and a legend
    rects = place_labels(anchors, sizes, 640, 360, reserved)
    assert all(r is not None for r in rects)
    assert rects[0] == (100, 50, 190, 68)  # the most important label sits where it wanted
    _no_two_intersect(rects)
    for r in rects:
        assert r[0] >= 0 and r[2] <= 640 and r[1] >= 0 and r[3] <= 360
        assert not any(intersects(r, q) for q in reserved)
        # moved down or sideways, near its anchor: within a few label heights / widths
        assert abs(r[1] - 50) <= 12 * 20 and abs(r[0] - 100) <= 640
    assert rects[1][1] > rects[0][1]  # the second moved down first, not sideways or up


def test_labels_on_the_image_edge_and_on_reserved_areas_stay_inside_and_free():
    anchors = [(630.0, -20.0), (-50.0, 400.0), (320.0, 5.0), (320.0, 5.0)]
    rects = place_labels(anchors, [(60, 16)] * 4, 640, 360, [(0, 0, 640, 28)])
    _no_two_intersect([r for r in rects if r is not None])
    for r in rects:
        assert r is not None and r[1] >= 28 and r[2] <= 640 and r[3] <= 360 and r[0] >= 0


def test_a_label_with_no_free_spot_is_left_out_rather_than_drawn_over_another():
    rects = place_labels([(0.0, 0.0)] * 3, [(60, 20)] * 3, 64, 44, gap=2)
    assert rects[0] is not None and rects[1] is not None and rects[2] is None
    _no_two_intersect(rects[:2])


def _overlapping_cell():
    """The demo cell with two more image zones exactly on cam0-protective and one on the
    robot box's top corner: four labels that all want the same place."""
    data = yaml.safe_load(Path(demo_cell_path()).read_text())
    poly = next(z for z in data["zones"] if z["id"] == "cam0-protective")
    for k, kind in enumerate(("protective", "warning", "mask")):
        extra = {key: v for key, v in poly.items() if key != "speed_scale"}
        extra.update(id=f"cam0-stop-{k}", kind=kind, name=f"copy {k}")
        if kind == "warning":
            extra["speed_scale"] = 0.3
        data["zones"].append(extra)
    data["zones"].append({"id": "robot-box", "kind": "protective", "shape": "polygon",
                          "camera": "cam0", "anchor": "bottom-centre",
                          "points_px": [[510, 140], [770, 140], [770, 400], [510, 400]]})
    return parse_cell(data)


def test_zone_labels_of_overlapping_zones_never_overlap_each_other_or_the_reserved_areas():
    cell = _overlapping_cell()
    frame = np.full((720, 1280, 3), 90, np.uint8)
    reserved = [(0, 0, 1280, HEADER_PX), legend_rect(1280, HEADER_PX + 4)]
    hits = {"cam0-stop-0", "robot-box", "robot-protective"}
    _, labels = draw_zones_labelled(frame, cell, "cam0", hits, reserved)
    texts = [x.text for x in labels]
    # every enabled zone of cam0 is labelled, the hit ones as HIT
    assert {"cam0-stop-0 HIT", "cam0-stop-1", "cam0-stop-2", "robot-box HIT",
            "robot-protective HIT", "cam0-protective"} <= set(texts)
    _no_two_intersect([x.rect for x in labels])
    for x in labels:
        assert not any(intersects(x.rect, r) for r in reserved), x
        assert x.colour == COLOURS_BGR[next(z.kind for z in cell.zones
                                            if x.text.split()[0] == z.id)]


# --- one colour per kind, in the preview and the video -----------------------------------------


def test_each_zone_kind_has_one_colour_in_the_preview_and_the_video(tmp_path):
    cell = parse_cell(yaml.safe_load(Path(demo_cell_path()).read_text()))
    frame = np.full((720, 1280, 3), 90, np.uint8)
    preview = draw_zones(frame, cell, "cam0", legend=True)
    video = _annotate_one(frame, cell)
    assert video[1].legend == LEGEND_KINDS
    for image, top in ((preview, LEGEND_TOP_PX), (video[0], HEADER_PX + 4)):
        x1, y1, _, _ = legend_rect(1280, top)
        for k, kind in enumerate(LEGEND_KINDS):  # the swatch of each row
            swatch = image[y1 + 4 + 18 * k + 9, x1 + 16]
            assert tuple(int(v) for v in swatch) == COLOURS_BGR[kind], kind
    # the watch zone's outline in the video (drawn by the health check) is the preview's colour
    assert COLOURS_BGR["watch"] == WATCH_BGR
    canvas = np.zeros((720, 1280, 3), np.uint8)
    (_, shelf), = watch_regions(cell, "cam0")
    draw_health(canvas, HealthReport("cam0", 0.0), [("shelf-watch", shelf)])
    x, y = np.round(shelf[0]).astype(int)
    assert tuple(int(v) for v in canvas[y, x]) == COLOURS_BGR["watch"]


def _annotate_one(frame: np.ndarray, cell) -> tuple[np.ndarray, Drawn]:
    from monitor.policy import PolicyConfig, PolicyInputs, initial_state, step

    state = initial_state()
    _, command = step(state, PolicyInputs(), 0.0, PolicyConfig())
    result = StepResult(0.0, command, True)
    return Annotator(cell, "cam0", watch_regions(cell, "cam0")).step(result, frame)


# --- a replay of a generated walk into the protective zone, with a refused reset -------------

FPS = 10.0
RESET_S = 1.5  # the person stands in the protective zone then: refused


@pytest.fixture(scope="module")
def walk(detector, tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("annotate")
    scene = DemoScene(fps=FPS, duration_s=2.2,
                      path=((0.0, -2.6, -0.3), (1.2, -0.4, -0.3), (9.0, -0.4, -0.3)))
    video = tmp / "walk.mp4"
    write_video(video, scene.frames(), FPS)
    cell = parse_cell(yaml.safe_load(Path(demo_cell_path()).read_text()))
    results: list[StepResult] = []
    out = tmp / "out"
    settings = ReplaySettings(out_dir=out, reset_at=(RESET_S,), progress=False)
    summary = replay(video, detector, cell, settings, publish=results.append)
    # the same drawing again on the same steps and frames: what each frame of the video shows
    band = (0.0, detector.foot_uncertainty_px(1280, 720))
    annotator = Annotator(cell, "cam0", watch_regions(cell, "cam0"), band)
    raw = _frames(video)
    drawn: list[tuple[np.ndarray, Drawn]] = []
    frames = iter(raw)
    for r in results:
        got = annotator.step(r, next(frames) if r.frame is not None else None)
        if got is not None:
            drawn.append(got)
    return out, results, summary, raw, _frames(out / "annotated.mp4"), drawn


def _frames(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    out = []
    try:
        while True:
            ok, image = cap.read()
            if not ok:
                return out
            out.append(image)
    finally:
        cap.release()


def test_every_annotated_frame_has_a_header_with_time_frame_and_camera(walk):
    _, results, summary, raw, annotated, drawn = walk
    frames = [r for r in results if r.frame is not None]
    assert len(annotated) == len(raw) == len(drawn) == len(frames) == summary.frames
    for k, (r, (image, d)) in enumerate(zip(frames, drawn, strict=True)):
        assert d.header == f"t {r.now:.2f} s   frame {k}   camera cam0"
        band = (slice(0, HEADER_PX - 2), slice(None))
        # the video's header band is not the camera's picture, and is the band drawn
        assert np.abs(annotated[k][band].astype(int) - raw[k][band]).mean() > 30
        assert np.abs(annotated[k][band].astype(int) - image[band]).mean() < 6


def test_the_box_label_and_the_command_name_the_same_person(walk):
    _, results, _, _, _, drawn = walk
    frames = [r for r in results if r.frame is not None]
    named = 0
    for r, (_, d) in zip(frames, drawn, strict=True):
        assert d.person_ids == tuple(r.track_ids)
        for reason in r.command.reasons:
            if reason.code == "protective_zone":
                assert reason.person in d.person_ids
                assert any(t.startswith(f"person {reason.person} ") for t in d.persons), \
                    (reason.message, d.persons)
                named += 1
    assert named >= 3  # the walk stands in the protective zone for several frames
    assert all(i >= 1 for _, d in drawn for i in d.person_ids)  # track ids, not row 0


def test_the_refused_reset_shows_when_it_happens_for_two_seconds(walk):
    out, results, summary, _, _, drawn = walk
    assert [(x["time_s"], x["accepted"]) for x in summary.resets] == [(RESET_S, False)]
    event = next(json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()
                 if '"reset"' in line)
    who = next(x.person for r in results if r.command.reset is not None
               for x in r.command.reasons if x.code == "protective_zone")
    text = f"reset by replay: {event['reset']['message']}"
    assert text.startswith(f"reset by replay: refused: person {who} in ")
    frames = [r for r in results if r.frame is not None]
    at = next(r.now for r in results if r.command.reset is not None)
    assert at == pytest.approx(RESET_S, abs=1e-6)
    shown = [r.now for r, (_, d) in zip(frames, drawn, strict=True) if text in d.events]
    # from the reset on, every frame to the end of the clip (it ends within HOLD_S)
    assert frames[-1].now < at + HOLD_S
    assert shown == [r.now for r in frames if r.now >= at] and len(shown) >= 5
    before = [d for r, (_, d) in zip(frames, drawn, strict=True) if r.now < RESET_S]
    assert before and not any(d.events for d in before)


def test_the_floor_range_behind_each_hit_is_drawn_under_its_box(walk):
    _, results, _, _, _, drawn = walk
    frames = [r for r in results if r.frame is not None]
    checked = 0
    for r, (_, d) in zip(frames, drawn, strict=True):
        hit_rows = {h.person for h in r.zone_report.hits if not h.lost}
        assert {fr.person for fr in d.floor_ranges} == {r.track_ids[i] for i in hit_rows}
        for fr in d.floor_ranges:
            row = r.track_ids.index(fr.person)
            x1, y1, x2, y2 = r.persons.boxes_px[row]
            assert fr.located and len(fr.points_px) >= 2 and "floor range" in fr.text
            u, v = fr.points_px[:, 0], fr.points_px[:, 1]
            # the feet positions project into the box's lower part (the feet pixel range)
            assert np.all((u > x1 - 5) & (u < x2 + 5)), (u, x1, x2)
            assert np.all((v > (y1 + y2) / 2) & (v < y2 + 60)), (v, y1, y2)
            if r.command.state == STOP:
                checked += 1
    assert checked >= 3


def test_zone_labels_in_every_frame_are_apart_and_the_legend_is_shown(walk):
    *_, drawn = walk
    for _, d in drawn:
        assert d.legend == LEGEND_KINDS
        _no_two_intersect([x.rect for x in d.zone_labels])
        assert {"robot-protective", "cam0-protective"} <= {x.text.split()[0]
                                                           for x in d.zone_labels}


def test_a_reset_or_alert_of_a_timer_tick_shows_on_the_next_frames_for_hold_s_then_goes():
    from monitor.policy import PolicyConfig, PolicyInputs, ResetRequest, initial_state, step
    from monitor.types import Alert

    config = PolicyConfig()
    state = initial_state()
    annotator = Annotator(None, "cam0", [])
    frame = np.full((360, 640, 3), 90, np.uint8)
    shown = []
    for k in range(40):
        t = k * 0.1
        reset = ResetRequest("anna", t) if k == 10 else None
        state, command = step(state, PolicyInputs(reset_request=reset), t, config)
        alerts = (Alert("camera_frozen", "critical", "cam0: no change for 2.0 s", "cam0", t),) \
            if k == 12 else ()
        tick = k in (10, 12)  # decided between two frames: no image
        got = annotator.step(StepResult(t, command, True, alerts=alerts),
                             None if tick else frame)
        assert (got is None) == tick
        if got is not None:
            shown.append((round(t, 1), got[1].events))
    with_reset = [t for t, ev in shown if any(e.startswith("reset by anna: ") for e in ev)]
    with_alert = [t for t, ev in shown if "alert camera_frozen: cam0: no change for 2.0 s" in ev]
    assert with_reset == [round(0.1 * k, 1) for k in range(11, 30) if k != 12]
    assert with_alert == [round(0.1 * k, 1) for k in range(13, 32)]


def test_a_burst_of_alerts_shows_the_newest_rows_only():
    from monitor.policy import PolicyConfig, PolicyInputs, initial_state, step
    from monitor.records.annotate import MAX_EVENT_ROWS
    from monitor.types import Alert

    _, command = step(initial_state(), PolicyInputs(), 0.0, PolicyConfig())
    alerts = tuple(Alert(f"kind_{k}", "warning", f"message {k}", "cam0", 0.0) for k in range(7))
    frame = np.full((360, 640, 3), 90, np.uint8)
    _, drawn = Annotator(None, "cam0", []).step(StepResult(0.0, command, True, alerts=alerts),
                                                frame)
    assert drawn.events == tuple(f"alert kind_{k}: message {k}"
                                 for k in range(7 - MAX_EVENT_ROWS, 7))


def test_a_kept_zone_drawing_draws_every_frame_as_a_fresh_one_would():
    # the cache keeps the shapes, the shadow and the label places between frames: the hits,
    # the header rows, the tool's pose, the image size and the cell (a zone swap) still change
    # what is drawn, frame by frame
    cells = [parse_cell(with_platform(0.5)),
             parse_cell(with_bench(demo_data(), 2.2, y=(-2.0, -1.6), x=(-0.5, 0.5),
                                   zone_id="cabinet")),
             cell_with(following(cylinder())), _overlapping_cell()]
    frame = np.random.default_rng(3).integers(0, 255, (720, 1280, 3), dtype=np.uint8)
    cache = ZoneDrawCache()
    seen = set()
    # each cell at two sizes, three frames each, then the first cell again (a swap back)
    for n, (cell, image, j) in enumerate(itertools.product(
            [*cells, cells[0]], (frame, frame[::2, ::2]), range(3))):
        hits = [z.id for z in cell.zones][:2] if j % 2 else []
        # a header band, or the top half of the image: labels move away from it
        reserved = [(0, 0, image.shape[1], HEADER_PX if j < 2 else image.shape[0] // 2)]
        tool = pose(-1.0 + 0.4 * j, -2.0) if j % 2 else None
        kept, kept_labels = draw_zones_labelled(image, cell, "cam0", hits, reserved, tool, cache)
        fresh, fresh_labels = draw_zones_labelled(image, cell, "cam0", hits, reserved, tool)
        assert np.array_equal(kept, fresh), f"frame {n}"
        assert kept_labels == fresh_labels, f"frame {n}"
        seen.add(kept.tobytes())
    assert len(seen) >= 22  # the frames drew different things
    # the zone that follows the tool is drawn where the tool is, never where it was kept
    here, there = (draw_zones_labelled(frame, cells[2], "cam0", (), (), pose(x, -2.0), cache)[0]
                   for x in (-1.0, 0.2))
    assert not np.array_equal(here, there)
