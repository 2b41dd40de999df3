"""Mask zones never hide a person: whole boxes only, before merging."""

from __future__ import annotations

import functools

import numpy as np

from monitor import zones as zn
from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig
from monitor.scene import Figure, draw_figure
from monitor.types import FrameInfo
from monitor.zones.mask_risk import mask_risk_lines, mask_risks
from monitor.zones.masks import MaskRule

W, H = 1280, 720
GREY = 120
CUTOUT = Figure((520.0, 640.0), 360.0)  # a person-coloured cut-out in front
PERSON = Figure((660.0, 560.0), 300.0)  # a real person just behind it, to its right


def _keep(rule: MaskRule, *boxes) -> list[bool]:
    return rule.keep(np.array(boxes, float)).tolist()


def test_a_box_wholly_inside_a_tight_mask_is_suppressed_only_if_it_is_the_object():
    rule = MaskRule([np.array([[100, 100], [300, 100], [300, 500], [100, 500]])], W, H, 0.0)
    assert _keep(rule, [100, 100, 300, 500]) == [False]  # exactly the mask: the object
    assert _keep(rule, [150, 200, 250, 400]) == [True]  # smaller than the object: a person
    assert _keep(rule, [600, 100, 700, 300]) == [True]  # elsewhere
    # a box reaching 2 px out keeps itself; the object's box inside the mask still goes
    assert _keep(rule, [100, 100, 300, 500], [250, 200, 302, 400]) == [False, True]


def test_the_box_error_margin_suppresses_a_cut_out_but_not_a_box_reaching_out():
    rule = MaskRule([np.array([[100, 100], [300, 100], [300, 500], [100, 500]])], W, H, 50.0)
    assert _keep(rule, [60, 80, 340, 540]) == [False]  # the cut-out's box, one cell too large
    assert _keep(rule, [200, 100, 360, 500]) == [True]  # reaches 60 px out: a person there
    assert _keep(rule, [250, 450, 330, 620]) == [True]  # below the mask


def test_a_person_inside_a_loose_mask_is_kept():
    """A mask 50 px larger than its object: the object alone is not its extent (the mask
    suppresses nothing), and a person standing in the slack beside it is kept."""
    obj = [150, 150, 250, 450]
    rule = MaskRule([np.array([[100, 100], [300, 100], [300, 500], [100, 500]])], W, H, 25.0)
    assert _keep(rule, obj) == [True]
    assert _keep(rule, [255, 200, 295, 480]) == [True]  # a slim person in the slack alone
    assert _keep(rule, obj, [252, 200, 295, 480]) == [True, True]  # touching the object
    check = rule.check(np.array([obj], float))
    assert check.unmatched == ("mask0",)
    tight = MaskRule([np.array([[150, 150], [250, 150], [250, 450], [150, 450]])], W, H, 25.0)
    assert _keep(tight, obj) == [False]
    # the same person beside a tight mask reaches out of it: kept, the object still goes
    assert _keep(tight, obj, [252, 200, 295, 480]) == [False, True]


def test_a_group_reaching_out_of_the_mask_reports_its_whole_box():
    """A person touching the object: their boxes inside the mask go with the object's, and the
    whole group's box is reported so the person is also checked as reaching into the mask."""
    rule = MaskRule([np.array([[100, 100], [300, 100], [300, 500], [100, 500]])], W, H, 0.0)
    obj, person = [100, 100, 300, 500], [250, 150, 380, 480]
    check = rule.check(np.array([obj, person], float))
    assert check.keep.tolist() == [False, True]
    assert check.touching.tolist() == [[100, 100, 380, 500]]
    assert rule.check(np.array([obj], float)).touching.shape == (0, 4)  # the object alone
    apart = rule.check(np.array([obj, [400, 150, 480, 480]], float))  # not touching it
    assert apart.keep.tolist() == [False, True] and apart.touching.shape == (0, 4)
    inner = rule.check(np.array([[150, 200, 250, 400]], float))  # wholly inside: kept whole
    assert inner.keep.tolist() == [True] and inner.touching.shape == (0, 4)


def test_a_larger_person_in_front_of_the_object_is_kept():
    rule = MaskRule([np.array([[100, 100], [300, 100], [300, 500], [100, 500]])], W, H, 25.0)
    # wholly inside the grown mask but 24 px taller than the object above and below: kept
    assert _keep(rule, [90, 76, 290, 524]) == [False]  # within the box error: the object
    assert _keep(rule, [110, 80, 290, 470]) == [True]  # shorter at the bottom by 30 px


def test_non_convex_masks_and_odd_boxes():
    ell = np.array([[0, 0], [400, 0], [400, 100], [100, 100], [100, 400], [0, 400]])
    rule = MaskRule([ell], W, H, 0.0)
    assert _keep(rule, [10, 10, 390, 90]) == [True]  # in the top bar, not the L's extent
    assert _keep(rule, [0, 0, 400, 400]) == [True]  # the extent, but not wholly inside
    assert _keep(rule, [np.nan, 0, 10, 10]) == [True]  # not finite: never suppressed
    assert _keep(rule, [50, 50, 50, 50]) == [True]  # empty box: never suppressed
    # the L's own extent in pieces that lie inside it: suppressed together
    assert _keep(rule, [0, 0, 400, 100], [0, 0, 100, 400]) == [False, False]


def test_no_masks_keep_everything():
    rule = MaskRule([], W, H, 50.0)
    assert not rule.active
    assert rule.keep(np.zeros((3, 4))).tolist() == [True, True, True]


def _pixels(fig: Figure) -> tuple[int, int, int, int]:
    img = np.zeros((H, W, 3), np.uint8)
    draw_figure(img, fig)
    ys, xs = np.nonzero(img.any(axis=2))
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1


def _cell(mask_grow_px: int = 0) -> zn.Cell:
    """A tight mask around the cut-out (grown by ``mask_grow_px``) and a protective image zone
    right of it, where the real person stands."""
    x1, y1, x2, y2 = _pixels(CUTOUT)
    g = mask_grow_px
    return zn.parse_cell({
        "version": 1, "name": "masks", "cameras": [{"id": "cam0", "width": W, "height": H}],
        "zones": [
            {"id": "cutout", "kind": "mask", "shape": "polygon", "camera": "cam0",
             "points_px": [[x1 - g, y1 - g], [x2 + g, y1 - g], [x2 + g, y2 + g],
                           [x1 - g, y2 + g]]},
            {"id": "stop", "kind": "protective", "shape": "polygon", "camera": "cam0",
             "points_px": [[x2 + 1, 200], [1000, 200], [1000, 700], [x2 + 1, 700]]},
        ]})


@functools.cache
def _frame(person: bool) -> np.ndarray:
    img = np.full((H, W, 3), GREY, np.uint8)
    if person:
        draw_figure(img, PERSON)
    draw_figure(img, CUTOUT)  # in front: it hides part of the person
    return img


def _run(detector, img: np.ndarray, cell: zn.Cell, n: int = 2):
    pipe = Pipeline(detector, "cam0", PolicyConfig(clear_time=0.1, restart_interlock="auto"),
                    cell)
    return [pipe.process(img, FrameInfo("cam0", i, i / 10, W, H), i / 10) for i in range(n)]


def test_without_the_mask_the_cut_out_and_the_person_merge_into_one_box(detector):
    persons = detector.detect(_frame(person=True))
    assert len(persons) == 1  # the situation the mask rule must survive
    x1, _, x2, _ = persons.boxes_px[0]
    cx1, _, cx2, _ = _pixels(CUTOUT)
    assert x1 <= cx1 + 5 and x2 > cx2 + 50


def test_a_real_person_merged_with_a_masked_cut_out_is_still_in_the_zone(detector):
    results = _run(detector, _frame(person=True), _cell())
    last = results[-1]
    assert last.masked_boxes > 0
    # the person's part outside the mask (the cut-out's cells did not join it), and the whole
    # group's box: the person may reach into the mask; the zone check takes the worse answer
    assert len(last.persons) == 2
    part, whole = sorted(last.persons.boxes_px.tolist(), key=lambda b: -b[0])
    cx1 = _pixels(CUTOUT)[0]
    assert part[0] > cx1 + 40
    assert whole[0] <= cx1 + 5 and whole[2] == part[2]
    assert {(h.zone_id, h.lost) for h in last.zone_report.hits} == {("stop", False)}
    assert last.command.state == "STOP"


def test_the_mask_suppresses_its_cut_out_alone(detector):
    results = _run(detector, _frame(person=False), _cell(), n=3)
    assert [len(r.persons) for r in results] == [0, 0, 0]
    assert results[-1].zone_report.hits == ()
    assert results[-1].command.state == "RUN"


def test_an_uncalibrated_mask_near_a_protective_zone_is_warned_about():
    """No 3D calibration: the person size at the mask is unknown, so it is graded as risky."""
    near = mask_risk_lines(_cell())
    assert [g for g, _ in near] == ["warning"]
    assert "'cutout'" in near[0][1] and "protective zone 'stop'" in near[0][1]
    assert "unknown" in near[0][1] and "missed STOP" in near[0][1]
    far = zn.parse_cell({
        "version": 1, "name": "far", "cameras": [{"id": "cam0", "width": W, "height": H}],
        "zones": [
            {"id": "poster", "kind": "mask", "shape": "polygon", "camera": "cam0",
             "points_px": [[10, 10], [100, 10], [100, 200], [10, 200]]},
            {"id": "stop", "kind": "protective", "shape": "polygon", "camera": "cam0",
             "points_px": [[600, 300], [900, 300], [900, 700], [600, 700]]}]})
    assert [g for g, _ in mask_risk_lines(far)] == ["note"]  # far from every alert zone


def _scenario_cell(name: str) -> zn.Cell:
    from monitor.replay import scenarios as sc

    return zn.parse_cell(sc.select([name])[0].zone_data())


def test_a_tight_and_a_loose_mask_are_graded_by_the_person_that_could_stand_there():
    """The cut-out's tight mask: a person standing in line with it looks like it (a warning,
    near the protective zone); the 50 px looser one: a whole person fits inside but can never
    fill its outline, so the rule keeps them (ok). Sizes from the scene camera's model."""
    (tight,) = mask_risks(_scenario_cell("mask-tight-behind"))
    (loose,) = mask_risks(_scenario_cell("mask-loose-behind"))
    assert tight.level == "hides" and tight.near_protective
    assert loose.level == "fits" and loose.near_protective
    # what a person at the foot looks like, for the same 1-2 m person range
    assert tight.person_h_px is not None and loose.person_h_px is not None
    assert 60 < tight.person_h_px[0] < tight.person_h_px[1] < 200
    assert loose.grown_px[0] > loose.person_w_px[1] and loose.grown_px[1] > loose.person_h_px[1]
    (grade_t, line_t), = mask_risk_lines(_scenario_cell("mask-tight-behind"))
    (grade_l, line_l), = mask_risk_lines(_scenario_cell("mask-loose-behind"))
    assert grade_t == "warning" and "can hide a whole person" in line_t
    assert "protective zone 'robot-protective'" in line_t and "missed STOP" in line_t
    assert grade_l == "ok" and "cannot fill its outline" in line_l


def test_mask_grades_follow_the_person_size_at_that_depth():
    """The same outline is a person's size near the camera and larger than anyone far away;
    a small one is smaller than anyone."""
    from monitor.replay import scenarios as sc

    data = sc.select(["mask-tight-behind"])[0].zone_data()
    (mask,) = [z for z in data["zones"] if z["kind"] == "mask"]
    (x1, y1), (x2, y2) = mask["points_px"][0], mask["points_px"][2]
    mask["points_px"] = [[x1, y2 - 6], [x1 + 6, y2 - 6], [x1 + 6, y2], [x1, y2]]
    (small,) = mask_risks(zn.parse_cell(data))
    assert small.level == "smaller"
    mask["points_px"] = [[x1 - 60, y1 - 150], [x2 + 60, y1 - 150], [x2 + 60, y2],
                         [x1 - 60, y2]]
    (large,) = mask_risks(zn.parse_cell(data))
    assert large.level == "larger" and "larger than any person there" in large.describe()


def test_volume_masks_count_through_their_image_outline():
    """A mask volume (a mannequin on the floor) masks by its outline in the camera's image."""
    import yaml

    from monitor.config import demo_cell_path

    data = yaml.safe_load(demo_cell_path().read_text())
    data["zones"] = [z for z in data["zones"] if z["kind"] != "mask"]
    data["zones"].append({"id": "mannequin", "kind": "mask", "shape": "box",
                          "min_m": [3.0, 2.0, 0.0], "max_m": [3.6, 2.6, 1.8]})
    cell = zn.parse_cell(data)
    rule = MaskRule.for_camera(cell, "cam0", W, H, 30.0)
    (outline,) = rule.polygons
    x1, y1 = outline.min(axis=0)
    x2, y2 = outline.max(axis=0)
    cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
    whole = [x1 + 1, y1 + 1, x2 - 1, y2 - 1]  # the mannequin's extent
    inner = [cx - 5, cy - 20, cx + 5, cy + 20]  # much smaller: a person, not the mannequin
    reaching = [cx - 5, cy - 20, x2 + 60, cy + 20]
    assert rule.keep(np.array([whole])).tolist() == [False]
    assert rule.keep(np.array([inner])).tolist() == [True]
    assert rule.keep(np.array([reaching])).tolist() == [True]
    assert rule.ids == ("mannequin",)
    half = MaskRule.for_camera(cell, "cam0", W // 2, H // 2, 15.0)  # a smaller stream
    assert half.keep(np.array([whole]) / 2).tolist() == [False]


def test_zones_validate_grades_masks(tmp_path, capsys):
    import json

    from monitor.cli import main
    from monitor.replay import scenarios as sc

    words = {}
    for name in ("mask-tight-front", "mask-loose-front"):
        path = tmp_path / f"{name}.yaml"
        path.write_text(json.dumps(sc.select([name])[0].zone_data()))
        assert main(["zones", "validate", str(path)]) == 0
        words[name] = capsys.readouterr()
    tight, loose = words["mask-tight-front"], words["mask-loose-front"]
    assert "warning: mask zone 'cutout-mask' in camera 'cam0' can hide a whole person" \
        in tight.err
    assert "ok: mask zone 'cutout-mask'" not in tight.out
    assert "ok: mask zone 'cutout-mask' in camera 'cam0': a whole person fits inside it" \
        in loose.out
    assert "cutout-mask" not in loose.err


def test_the_detector_hook_sees_raw_boxes_in_frame_pixels(detector):
    """``pre_merge`` gets the raw boxes (one per grid cell here) in the frame's pixels."""
    seen = []

    def record(boxes):
        seen.append(boxes.copy())
        return np.ones(len(boxes), bool)

    img = _frame(person=False)
    merged = detector.detect_timed(img, pre_merge=record).persons
    (raw,) = seen
    assert len(raw) > 5 and len(merged) == 1
    assert np.allclose(raw.min(axis=0)[:2], merged.boxes_px[0][:2], atol=1.0)
    assert np.allclose(raw.max(axis=0)[2:], merged.boxes_px[0][2:], atol=1.0)
    none = detector.detect_timed(img, pre_merge=lambda b: np.zeros(len(b), bool)).persons
    assert len(none) == 0
