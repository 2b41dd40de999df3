"""`monitor commission walk` on a generated scene with ground truth: a person walks into the
protective zone twice (from the side, then through its front edge) while a cabinet hides the
zone's front-left corner from the only camera. The walk finds both entries with their time to
STOP, the floor the person was seen on, and the cells behind the cabinet as blind spots; the
report shows every protective zone's coverage and each entry's time to STOP."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from monitor.cli import main
from monitor.commission.floor import zone_floors
from monitor.commission.pictures import BLIND_BGR
from monitor.commission.walk import StepSample, analyse
from monitor.replay import scenarios as sc
from monitor.scene import cell as scene_cell
from monitor.scene import write_video
from monitor.zones import parse_cell, write_cell_data
from tests.helpers import commissioner_key, one_error_line
from tests.processes import one_inference_thread

CABINET = scene_cell.Block("cabinet", (-1.0, -1.5, 0.0), (-0.1, -1.1, 1.9))
BEHIND_CABINET = (-0.625, -0.875)  # a protective floor cell right behind it
OPEN_FRONT = (0.625, -0.875)  # its mirror image, in open view
RADIUS_M = 0.3  # the zone file's person radius: the cylinder overlaps the zone from here


def _scene(blocks=(CABINET,)) -> scene_cell.CellScene:
    walker = scene_cell.Walker((
        (0.0, 2.4, -0.6), (1.5, 0.6, -0.6), (2.5, 0.6, -0.6), (4.0, 2.4, -0.6),
        (5.0, 2.4, -2.0), (6.0, 0.5, -2.0), (7.5, 0.5, -0.5), (9.0, 0.5, -2.2)))
    return scene_cell.CellScene((walker,), blocks=blocks, fps=5, duration_s=9.6)


def _zone_data(scene: scene_cell.CellScene) -> dict:
    # the cabinet hides floor a crouching person could stand on: accepted, so the walk shows it
    return sc.Scenario("walk", "walk test", scene, unobserved_ok=True).zone_data()


def _truth_entries(truth) -> list[float]:
    inside = [sc.rect_distance(t.persons[0].floor_m) < RADIUS_M for t in truth]
    return [truth[k].time_s for k in range(len(truth))
            if inside[k] and (k == 0 or not inside[k - 1])]


@pytest.fixture(scope="module")
def walked(tmp_path_factory, synthetic_model):
    tmp = tmp_path_factory.mktemp("walk")
    scene = _scene()
    truth = write_video(tmp / "walk.mp4", scene.frames(), scene.fps)
    write_cell_data(_zone_data(scene), tmp / "cell.yaml")
    (tmp / "monitor.toml").write_text(one_inference_thread(
        f'[camera]\nid = "cam0"\nsource = "walk.mp4"\n[model]\npath = "{synthetic_model}"\n'
        '[zones]\nfile = "cell.yaml"\n'))
    # one straight walk through the zones: its entries and times to STOP are what these tests
    # read, not coverage (a crouching person's visibility counts more protective floor as
    # visible than one pass walks: 3 of 36 cells, under the default 10 %)
    assert main(["commission", "walk", "--video", str(tmp / "walk.mp4"), "--config",
                 str(tmp / "monitor.toml"), "--out", str(tmp / "walk"), "--no-video",
                 "--min-walked", "0.05"]) == 0
    assert main(["commission", "report", "--config", str(tmp / "monitor.toml"), "--walk",
                 str(tmp / "walk"), "--out", str(tmp / "report.html"),
                 "--key", str(commissioner_key(tmp))]) == 0
    walk = json.loads((tmp / "walk" / "walk.json").read_text())
    return tmp, walk, _truth_entries(truth), (tmp / "report.html").read_text()


@pytest.mark.slow
def test_each_entry_is_found_with_its_time_to_stop(walked):
    _, walk, truth, _ = walked
    zone = next(z for z in walk["zones"] if z["zone_id"] == "robot-protective")
    assert len(truth) == 2
    assert len(zone["entries"]) == len(truth), zone["entries"]
    for entry, true_in in zip(zone["entries"], truth, strict=True):
        # the zone check holds the person's whole floor range: never later than the truth
        # by more than a frame, and never long before it
        assert true_in - 0.6 <= entry["entry_s"] <= true_in + 0.2, (entry, true_in)
        assert entry["time_to_stop_s"] is not None and 0 <= entry["time_to_stop_s"] <= 0.2
        assert entry["exit_s"] is not None and entry["frames_inside"] >= 5
    assert zone["seen_cells"] >= 2 and zone["visible_cells"] < zone["cells"]
    assert walk["zones_hash"] and walk["frames"] == 48


@pytest.mark.slow
def test_the_floor_behind_a_fixture_is_a_blind_spot(walked):
    tmp, walk, _, _ = walked
    zone = next(z for z in walk["zones"] if z["zone_id"] == "robot-protective")
    blind = {tuple(p) for p in zone["blind_spots"]}
    assert BEHIND_CABINET in blind and OPEN_FRONT not in blind
    floor = cv2.imread(str(tmp / "walk" / "floor.png"))
    camera = cv2.imread(str(tmp / "walk" / "camera-cam0.png"))
    for image in (floor, camera):
        assert (np.abs(image.astype(int) - BLIND_BGR).sum(axis=2) == 0).sum() > 20


def test_without_the_fixture_that_floor_is_visible():
    """The same cell without the cabinet: the cell behind it is seen (the cabinet is the
    cause, not the camera's view)."""
    with_cabinet = zone_floors(parse_cell(_zone_data(_scene())))
    without = zone_floors(parse_cell(_zone_data(_scene(blocks=()))))

    def visible(floors, point) -> bool:
        f = next(f for f in floors if f.zone_id == "robot-protective")
        k = int(f.cell_of(np.array([point]))[0])
        return bool(f.visible[k])
    assert not visible(with_cabinet, BEHIND_CABINET) and visible(without, BEHIND_CABINET)
    assert visible(with_cabinet, OPEN_FRONT)


@pytest.mark.slow
def test_the_report_shows_every_protective_zone_and_each_time_to_stop(walked):
    _, walk, _, html = walked
    protective = [z for z in walk["zones"] if z["kind"] == "protective"]
    assert protective
    for z in protective:
        assert f'id="walk1-{z["zone_id"]}"' in html
        assert f"<td>{z['seen_cells']} ({100 * z['seen_fraction']:.0f} %)</td>" in html
        for k, e in enumerate(z["entries"], 1):
            row = f"<tr><td>{k}</td><td>{e['entry_s']:.4g}</td><td>{e['exit_s']:.4g}</td>" \
                  f"<td>{e['stop_s']:.4g}</td><td>{e['time_to_stop_s']:.4g}</td>"
            assert row in html
    assert "floor cells no camera sees (blind spots)" in html  # an open warning
    assert html.count("data:image/png;base64,") >= 4  # 2 zone pictures + 2 walk pictures


def test_entries_gaps_and_times_from_decisions():
    """The analysis alone: a person seen at 0.0-0.4 s outside, in the zone at 0.6-1.0 s with
    the STOP at 0.65 s (a timer tick), missed for three frames, seen again inside."""
    floors = zone_floors(parse_cell(_zone_data(_scene())))
    outside, inside = ((2.0, -2.0),), ((0.5, -0.5),)
    s = []
    for k in range(12):
        t = k * 0.2
        if 6 <= k <= 8:
            s.append(StepSample(t, True, "STOP", ("robot-protective",)))  # missed
            continue
        feet = inside if k >= 3 else outside
        hit = ("robot-protective",) if k >= 3 else ()
        state = "STOP" if k >= 4 else "RUN"
        s.append(StepSample(t, True, state, hit if k >= 4 else (), hit, 1, feet))
        if k == 3:
            s.append(StepSample(0.65, False, "STOP", ("robot-protective",)))
    result = analyse(s, floors)
    zone = result.zone("robot-protective")
    assert len(zone.entries) == 2  # the gap ends the first entry; seen again: a second
    first = zone.entries[0]
    assert first.entry_s == pytest.approx(0.6) and first.stop_s == pytest.approx(0.65)
    assert first.time_to_stop_s == pytest.approx(0.05) and first.exit_s == pytest.approx(1.2)
    assert [(g.from_s, g.frames_missed) for g in zone.gaps] == [(pytest.approx(1.0), 3)]
    assert zone.seen_cells == 1 and result.frame_interval_s == pytest.approx(0.2)


def test_a_missing_video_is_one_line(tmp_path, capsys):
    assert main(["commission", "walk", "--video", str(tmp_path / "nope.mp4")]) == 2
    assert "nope.mp4: no such video" in one_error_line(capsys)


@pytest.mark.slow
def test_record_a_walk_from_the_configs_camera(tmp_path, synthetic_model, capsys):
    """--record: the config's camera (the demo scene, unpaced) into walk.mp4 at 10 fps, then
    the same analysis (the demo cell's image zones have entries, no floor)."""
    (tmp_path / "monitor.toml").write_text(
        '[camera]\nsource = "synthetic:demo"\nrealtime = false\nloop = false\n'
        f'[model]\npath = "{synthetic_model}"\n')
    out = tmp_path / "walk"
    # one second of the demo: nobody is detected yet, so the walk FAILs (exit 1) and says why
    assert main(["commission", "walk", "--record", "1", "--config", str(tmp_path / "monitor.toml"),
                 "--out", str(out), "--no-video"]) == 1
    printed = capsys.readouterr().out
    assert "recorded 10 frames at 10 fps" in printed and "0 repeated" in printed
    assert "FAIL camera cam0: nobody was detected in its walk" in printed
    walk = json.loads((out / "walk.json").read_text())
    assert walk["frames"] == 10 and walk["video"] == "walk.mp4" and walk["camera"] == "cam0"
    kinds = {z["zone_id"]: z["cells"] for z in walk["zones"]}
    assert kinds["robot-protective"] > 0 and kinds["cam0-protective"] == 0
