"""`monitor commission walk --video --truth` on generated walks with ground truth
(``monitor.commission.walk_scene``): the walk docs/commissioning.md asks for (around the
protective zone, crouching at each corner) is seen at every corner with a STOP at each entry,
and the report never claims a corner seen in more frames than the person could be seen there;
the same walk past a cabinet that hides a crouching person reports the blind corner; a person
first in the zone in a frame the detector misses shows a time to STOP of one frame interval."""

from __future__ import annotations

import json
import math

import pytest

from monitor.cli import main
from monitor.commission.floor import zone_floors
from monitor.commission.truth import TruthFrame, read_truth
from monitor.commission.walk import CORNER_M, StepSample, analyse
from monitor.commission.walk_scene import (
    HIDDEN_CORNER,
    ZONES_FILE,
    corner_walk,
    late_detection_walk,
    walk_zone_data,
    write_walk_scene,
    zone_corners,
)
from monitor.replay.scenarios import PROTECTIVE
from monitor.zones import parse_cell
from tests.helpers import commissioner_key, one_error_line
from tests.processes import one_inference_thread

ZONE = "robot-protective"


def _walk(tmp, model, scene, missed=frozenset(), truth=True):
    truths = write_walk_scene(tmp, scene, missed)
    (tmp / "monitor.toml").write_text(one_inference_thread(
        f'[camera]\nid = "cam0"\nsource = "walk.mp4"\n[model]\npath = "{model}"\n'
        f'[zones]\nfile = "{ZONES_FILE}"\n'))
    args = ["commission", "walk", "--video", str(tmp / "walk.mp4"), "--config",
            str(tmp / "monitor.toml"), "--out", str(tmp / "walk"), "--no-video"]
    # 0: every zone PASSes; 1: a zone FAILs (the hidden corner's walk, a short one), which the
    # tests of the verdict check (tests/test_commission_verdict.py); not 2: no error
    assert main([*args, "--truth", str(tmp / "truth.json")] if truth else args) in (0, 1)
    walk = json.loads((tmp / "walk" / "walk.json").read_text())
    return walk, truths


def _zone(walk):
    return next(z for z in walk["zones"] if z["zone_id"] == ZONE)


def _inside(p) -> bool:
    (x0, y0), (x1, y1) = PROTECTIVE
    return x0 <= p.floor_m[0] <= x1 and y0 <= p.floor_m[1] <= y1


def _near(truths, corner, visible_only=False):
    """Frames the truth has the person on the zone's floor within CORNER_M of the corner
    (``visible_only``: and some of them in view)."""
    out = 0
    for t in truths:
        for p in t.persons:
            if _inside(p) and math.dist(p.floor_m, corner) <= CORNER_M \
                    and (not visible_only or p.box_px is not None):
                out += 1
                break
    return out


@pytest.fixture(scope="module")
def corners(tmp_path_factory, synthetic_model):
    tmp = tmp_path_factory.mktemp("corners")
    scene, visits = corner_walk()
    walk, truths = _walk(tmp, synthetic_model, scene)
    return tmp, walk, truths, visits


@pytest.fixture(scope="module")
def hidden(tmp_path_factory, synthetic_model):
    tmp = tmp_path_factory.mktemp("hidden")
    scene, _ = corner_walk(hidden_corner=True, visits=(HIDDEN_CORNER,))
    walk, truths = _walk(tmp, synthetic_model, scene)
    assert main(["commission", "report", "--config", str(tmp / "monitor.toml"), "--walk",
                 str(tmp / "walk"), "--out", str(tmp / "report.html"),
                 "--key", str(commissioner_key(tmp))]) == 0
    return walk, truths, (tmp / "report.html").read_text()


@pytest.mark.slow
def test_every_corner_is_seen_crouching_with_a_stop_at_each_entry(corners):
    _, walk, truths, visits = corners
    zone = _zone(walk)
    assert walk["by_truth"] and walk["truth"] == "truth.json"
    assert [tuple(c["corner_m"]) for c in zone["corners"]] == list(zone_corners())
    crouching = {t.index for t in truths if t.persons[0].posture == "crouching"}
    assert crouching, "the walker never crouched"
    for c, visit in zip(zone["corners"], visits, strict=True):
        corner = tuple(c["corner_m"])
        assert c["frames_near"] == _near(truths, corner), c  # the report's truth is the scene's
        # seen: never in more frames than the person was in view there, and in view they are
        # found (a crouching person included)
        assert c["seen"] and c["frames_seen"] <= _near(truths, corner, visible_only=True), c
        assert c["frames_seen"] == c["frames_near"], c
        assert c["blind_cells"] == 0
        # the crouch lies within an entry that the monitor stopped
        inside = [e for e in zone["entries"]
                  if e["entry_s"] <= visit.crouch_s[0] and (e["exit_s"] or math.inf)
                  >= visit.crouch_s[1]]
        assert len(inside) == 1 and inside[0]["stop_s"] is not None, (visit, zone["entries"])
    assert zone["entries"] and all(e["stop_s"] is not None for e in zone["entries"])
    assert zone["blind_spots"] == []


@pytest.mark.slow
def test_a_corner_hidden_behind_a_cabinet_is_reported(hidden):
    """The walk that can fail: a cabinet hides the crouching person at the far-left corner.
    The report shows blind cells there and the person seen in fewer frames than they were
    there, never in more than they could be seen in; and says so among its warnings."""
    walk, truths, html = hidden
    zone = _zone(walk)
    (c,) = [c for c in zone["corners"] if tuple(c["corner_m"]) == zone_corners()[HIDDEN_CORNER]]
    hidden_frames = sum(t.persons[0].box_px is None for t in truths
                        if _inside(t.persons[0]))
    assert hidden_frames >= 4, "the cabinet hides nothing: the scene is wrong"
    assert c["blind_cells"] > 0 and c["frames_near"] == _near(truths, c["corner_m"])
    assert c["frames_seen"] <= _near(truths, c["corner_m"], visible_only=True)
    assert c["frames_seen"] < c["frames_near"]
    blind = {tuple(p) for p in zone["blind_spots"]}
    assert (-0.875, 0.875) in blind  # the crouch's own floor cell
    x, y = c["corner_m"]
    assert c["frames_seen"] > 0  # standing up there, their head shows over the cabinet
    assert (f"corner ({x:g}, {y:g}) m: the person was seen in {c['frames_seen']} of the "
            f"{c['frames_near']} frames they were there") in html
    # the crouch is an entry the monitor held stopped (the lost person's hold), no gap in it
    assert all(e["stop_s"] is not None for e in zone["entries"])


@pytest.mark.slow
def test_time_to_stop_counts_from_the_first_frame_truly_inside(tmp_path, synthetic_model):
    """A person first in the zone in a frame the detector misses: with the ground truth the
    entry starts at that frame and the STOP comes one frame interval later (the first
    detection); the entry's first detection is that STOP's frame."""
    scene, missed = late_detection_walk()
    walk, truths = _walk(tmp_path, synthetic_model, scene, missed)
    zone = _zone(walk)
    (k,) = missed
    entry = zone["entries"][0]
    assert entry["entry_s"] == pytest.approx(truths[k].time_s)
    assert entry["detected_s"] == pytest.approx(truths[k + 1].time_s)
    assert entry["stop_s"] == pytest.approx(entry["detected_s"])
    assert entry["time_to_stop_s"] == pytest.approx(walk["frame_interval_s"])
    assert walk["frame_interval_s"] == pytest.approx(1 / scene.fps)


@pytest.mark.slow
def test_a_truth_of_another_video_is_one_line(tmp_path, synthetic_model, capsys):
    scene, _ = corner_walk(visits=(0,))
    write_walk_scene(tmp_path, scene)
    other = read_truth(tmp_path / "truth.json")
    (tmp_path / "short.json").write_text(json.dumps({"frames": [
        {"time_s": f.time_s, "floor_m": [list(p) for p in f.floor_m]} for f in other[:-3]]}))
    (tmp_path / "bad.json").write_text('{"frames": [{"time_s": 0}]}')
    base = ["commission", "walk", "--video", str(tmp_path / "walk.mp4"), "--zones",
            str(tmp_path / ZONES_FILE), "--model", str(synthetic_model), "--out",
            str(tmp_path / "walk"), "--no-video", "--truth"]
    assert main([*base, str(tmp_path / "short.json")]) == 2
    assert "short.json: " in (line := one_error_line(capsys)) and "another video" in line
    assert main([*base, str(tmp_path / "bad.json")]) == 2
    assert "bad.json: frame 0: needs time_s and floor_m" in one_error_line(capsys)
    assert main([*base, str(tmp_path / "nope.json")]) == 2
    assert "nope.json: no such ground-truth file" in one_error_line(capsys)


def test_the_truth_starts_an_entry_before_its_first_detection():
    """The analysis alone, 0.2 s frames: the person truly steps in at 0.4 s, is missed there
    and detected inside at 0.6 s with the STOP: one frame interval to STOP with the truth, 0
    without (the entry is then the detection); the corner near them counts the frames."""
    floors = zone_floors(parse_cell(walk_zone_data(corner_walk(visits=(0,))[0])))
    outside, inside = (-1.7, -1.7), (-0.875, -0.875)
    s, truth = [], []
    for k in range(8):
        t = k * 0.2
        where = outside if k < 2 or k >= 6 else inside
        truth.append(TruthFrame(t, (where,)))
        if k == 2:  # missed
            s.append(StepSample(t, True, "RUN", ()))
        elif where == inside:
            s.append(StepSample(t, True, "STOP", (ZONE,), (ZONE,), 1, ((-0.9, -0.9),)))
        else:
            s.append(StepSample(t, True, "RUN", (), (), 1, ((-1.7, -1.7),)))
    with_truth = analyse(s, floors, truth=truth).zone(ZONE)
    (e,) = with_truth.entries
    assert (e.entry_s, e.detected_s, e.stop_s) == pytest.approx((0.4, 0.6, 0.6))
    assert e.time_to_stop_s == pytest.approx(0.2) and e.frames_inside == 4
    near_left = with_truth.corners[0]
    assert (near_left.frames_near, near_left.frames_seen) == (4, 3)
    (e,) = analyse(s, floors).zone(ZONE).entries
    assert (e.entry_s, e.time_to_stop_s) == pytest.approx((0.6, 0.0))
