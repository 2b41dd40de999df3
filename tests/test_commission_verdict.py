"""A walk that proves something (issue 47): the verdict per zone and camera FAILs, with the
reason, while nobody was detected, a protective zone was never entered, too little of its floor
was walked, a camera was frozen, or a camera was never walked; several walks merge; the demo
walk with ground truth PASSes for the zones it enters; a report lists the verdict first."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from monitor.cli import main
from monitor.commission import details
from monitor.commission.floor import zone_floors
from monitor.commission.verdict import (
    FAIL,
    PASS,
    WalkLimits,
    camera_verdicts,
    merge_zone,
    zone_verdicts,
)
from monitor.commission.walk import StepSample, analyse
from monitor.commission.walk_scene import ZONES_FILE, corner_walk, walk_zone_data, write_walk_scene
from monitor.zones import parse_cell
from tests.helpers import commissioner_key
from tests.processes import one_inference_thread

ZONE = "robot-protective"  # the generated walk's 2 x 2 m protective zone, (-1, -1)-(1, 1) m


@pytest.fixture(scope="module")
def cell():
    return parse_cell(walk_zone_data(corner_walk()[0]))


def walk_json(cell, feet_by_frame, *, faults=(), camera="cam0") -> dict:
    """A walk.json of frames at 5 fps: in each, the feet given (a STOP naming the zone while
    one is inside) and the camera faults given."""
    floors = zone_floors(cell)
    inside_zone = next(f for f in floors if f.zone_id == ZONE)
    samples = []
    for k, feet in enumerate(feet_by_frame):
        inside = bool(feet) and bool((inside_zone.cell_of(np.array(feet)) >= 0).any())
        named = (ZONE,) if inside else ()
        samples.append(StepSample(k * 0.2, True, "STOP" if inside else "RUN", named, named,
                                  len(feet), tuple(feet), faults if k >= 2 else ()))
    data = analyse(samples, floors).to_dict()
    return {**data, "camera": camera, "zones_hash": cell.config_hash, "video": "w.mp4"}


def verdict_of(verdicts, subject):
    return next(v for v in verdicts if v.subject == subject)


def test_nobody_detected_fails_every_zone_with_the_reason(cell):
    walk = walk_json(cell, [()] * 20)
    zones = zone_verdicts(details.zones(cell), [walk])
    for v in zones:
        assert v.verdict == FAIL and "nobody was detected in the walk (20 frames)" in v.reasons
    assert "the protective zone was never entered" in verdict_of(zones, ZONE).reasons
    assert verdict_of(camera_verdicts(["cam0"], [walk]), "cam0").verdict == FAIL


def test_a_protective_zone_never_entered_fails(cell):
    walk = walk_json(cell, [((3.0, 3.0),)] * 20)  # seen all the time, never inside
    v = verdict_of(zone_verdicts(details.zones(cell), [walk]), ZONE)
    assert v.verdict == FAIL and v.reasons[0] == "the protective zone was never entered"
    assert verdict_of(camera_verdicts(["cam0"], [walk]), "cam0").verdict == PASS


def test_a_frozen_camera_fails_its_zones_and_itself(cell):
    path = [((0.1 * k - 0.9, -0.7),) for k in range(19)]  # across the zone
    ok = walk_json(cell, path)
    assert verdict_of(zone_verdicts(details.zones(cell), [ok]), ZONE).verdict == PASS
    frozen = walk_json(cell, path, faults=(("cam0", "camera_frozen"),))
    v = verdict_of(zone_verdicts(details.zones(cell), [frozen]), ZONE)
    assert v.verdict == FAIL and "camera cam0 was frozen in 17 frames (walk 1)" in v.reasons
    cam = verdict_of(camera_verdicts(["cam0"], [frozen]), "cam0")
    assert cam.verdict == FAIL and "frozen in 17 frames" in cam.reasons[0]


def test_little_floor_walked_fails_and_the_share_is_settable(cell):
    walk = walk_json(cell, [((-0.7, -0.7),)] * 10)  # inside, on one spot
    v = verdict_of(zone_verdicts(details.zones(cell), [walk]), ZONE)
    assert v.verdict == FAIL and "of the zone's visible floor was walked" in v.reasons[0]
    assert "at least 10 % asked" in v.reasons[0]
    lenient = zone_verdicts(details.zones(cell), [walk], WalkLimits(min_walked=0.0))
    assert verdict_of(lenient, ZONE).verdict == PASS


def test_a_camera_never_walked_fails(cell):
    walk = walk_json(cell, [((0.1 * k - 0.9, -0.7),) for k in range(19)])
    cams = camera_verdicts(["cam0", "cam1"], [walk])
    assert verdict_of(cams, "cam0").verdict == PASS
    assert verdict_of(cams, "cam1").reasons == ("never walked: no walk was recorded from this "
                                              "camera",)
    image_zone = {"id": "cam1-stop", "kind": "protective", "enabled": True, "camera": "cam1"}
    v = zone_verdicts([image_zone], [walk])[0]
    assert v.verdict == FAIL and "its camera cam1 was never walked" in v.reasons


def test_two_walks_merge(cell):
    left = walk_json(cell, [((-0.9 + 0.1 * k, -0.5),) for k in range(10)])
    right = walk_json(cell, [((0.0 + 0.1 * k, 0.5),) for k in range(10)])
    one, both = merge_zone(ZONE, [left]), merge_zone(ZONE, [left, right])
    assert both["seen_cells"] > one["seen_cells"]
    assert [e["walk"] for e in both["entries"]] == [1, 2]
    assert both["walks"] == [1, 2]


@pytest.mark.slow
def test_the_demo_walk_with_truth_passes_and_the_report_merges_two_walks(tmp_path,
                                                                        synthetic_model,
                                                                        capsys):
    write_walk_scene(tmp_path, corner_walk()[0])
    (tmp_path / "monitor.toml").write_text(one_inference_thread(
        f'[camera]\nid = "cam0"\nsource = "walk.mp4"\n[model]\npath = "{synthetic_model}"\n'
        f'[zones]\nfile = "{ZONES_FILE}"\n[service]\ncommissioners_file = "commissioners"\n'))
    args = ["commission", "walk", "--video", str(tmp_path / "walk.mp4"), "--config",
            str(tmp_path / "monitor.toml"), "--truth", str(tmp_path / "truth.json"),
            "--no-video"]
    assert main([*args, "--out", str(tmp_path / "walk")]) == 0
    printed = capsys.readouterr().out
    assert f"PASS protective zone {ZONE}" in printed and "walk test PASS" in printed
    # a frozen camera: the same walk with one frame held for 3 s in the middle
    frozen = _freeze(tmp_path / "walk.mp4", tmp_path / "frozen.mp4", at=20, frames=45)
    assert main(["commission", "walk", "--video", str(frozen), "--config",
                 str(tmp_path / "monitor.toml"), "--no-video",
                 "--out", str(tmp_path / "frozen")]) == 1
    printed = capsys.readouterr().out
    assert f"FAIL protective zone {ZONE}" in printed and "camera cam0 was frozen" in printed
    # the report takes both walks (a second --walk is not dropped) and the verdict first
    key = commissioner_key(tmp_path)
    assert main(["commission", "report", "--config", str(tmp_path / "monitor.toml"), "--walk",
                 str(tmp_path / "walk"), "--walk", str(tmp_path / "walk"), "--key", str(key),
                 "--out", str(tmp_path / "report.html")]) == 0
    html = (tmp_path / "report.html").read_text()
    assert html.index('id="summary"') < html.index('id="warnings"') < html.index(
        'id="identity"')
    assert "<h3>Walk 1: walk.mp4</h3>" in html and "<h3>Walk 2: walk.mp4</h3>" in html
    assert f'<td>protective zone {ZONE}</td><td class="PASS">PASS</td>' in html
    walk = json.loads((tmp_path / "walk" / "walk.json").read_text())
    assert walk["detected_frames"] > 0 and walk["camera_faults"] == {}


def _freeze(src: Path, dst: Path, at: int, frames: int) -> Path:
    cap = cv2.VideoCapture(str(src))
    fps = cap.get(cv2.CAP_PROP_FPS)
    images = []
    while True:
        ok, image = cap.read()
        if not ok:
            break
        images.append(image)
    cap.release()
    held = images[:at] + [images[at]] * frames + images[at:]
    h, w = held[0].shape[:2]
    dst = dst.with_suffix(".avi")  # MJPG: every held frame decodes to the same image
    out = cv2.VideoWriter(str(dst), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    for image in held:
        out.write(image)
    out.release()
    return dst
