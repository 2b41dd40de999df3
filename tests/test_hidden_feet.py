"""Feet that are cut off are not feet (docs/occlusion.md, "What seen means"): a box ending on a
horizontal edge of the commissioning reference is placed from its head as a range towards the
camera, whether the fixture is declared or not, and a person placed that way never ends
another person's hold; the visible fraction of the smallest posture decides which floor a
camera sees."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from monitor import zones as zn
from monitor.geometry import occlusion as occ
from monitor.geometry.edges import horizontal_edges
from monitor.scene.cell import Block, CellScene, Walker, zone_data
from monitor.tracking.tracks import PersonTracker
from monitor.types import FrameInfo, Persons

W, H = 1280, 720


def image_cell() -> zn.Cell:
    return zn.parse_cell({
        "version": 1, "name": "cut",
        "cameras": [{"id": "cam0", "width": W, "height": H}],
        "zones": [{"id": "stop", "kind": "protective", "shape": "polygon", "camera": "cam0",
                   "points_px": [[500, 300], [800, 300], [800, 710], [500, 710]]}]})


def test_a_cut_off_person_standing_over_a_lost_persons_area_never_ends_its_hold():
    # A is seen inside, then lost (crouched behind a fixture); B stands behind A, their box
    # cut off above A's feet (placed as a range down to row 700): B's possible feet cover all
    # of A's area. Before, B "explained" A's area after clear_time (a person who came
    # back under a new id) and A's hold ended while B stood there.
    cell = image_cell()
    tracker = PersonTracker()
    zones_of = functools.partial(zn.check_persons, cell, "cam0")
    a = [610.0, 360.0, 690.0, 600.0]
    b = [560.0, 200.0, 760.0, 330.0]  # another person, above A in the image: a new track
    holds = []
    for k in range(40):
        t = k / 10
        boxes, cut = ([a], [np.nan]) if k < 5 else ([b], [700.0])
        info = FrameInfo("cam0", k, t, W, H)
        persons = Persons(np.array(boxes, np.float32), np.full(1, 0.9, np.float32), info)
        report = zn.check_persons(cell, "cam0", persons.boxes_px)
        tracker.update(persons, report, t, (W, H), zones_of, clear_time=1.0,
                       zones_key="test", feet_bottom_px=np.array(cut))
        holds.append(bool(tracker.holds))
    assert all(holds[5:]), holds  # A's hold stands while B stands there


def test_without_the_cut_rows_the_same_scene_ends_the_hold():
    # the test above can fail: B's box taken as feet in view explains A's area
    cell = image_cell()
    tracker = PersonTracker()
    zones_of = functools.partial(zn.check_persons, cell, "cam0")
    a = [610.0, 360.0, 690.0, 600.0]
    b = [560.0, 200.0, 760.0, 330.0]  # another person, above A in the image: a new track
    for k in range(40):
        t = k / 10
        boxes = [a] if k < 5 else [[b[0], b[1], b[2], 700.0]]
        info = FrameInfo("cam0", k, t, W, H)
        persons = Persons(np.array(boxes, np.float32), np.full(1, 0.9, np.float32), info)
        report = zn.check_persons(cell, "cam0", persons.boxes_px)
        tracker.update(persons, report, t, (W, H), zones_of, clear_time=1.0,
                       zones_key="test")
    assert not tracker.holds


def test_a_lost_cut_off_persons_area_reaches_down_to_where_their_feet_may_be():
    tracker = PersonTracker()
    b = [610.0, 330.0, 690.0, 450.0]
    for k, boxes in enumerate(([b], [])):
        info = FrameInfo("cam0", k, k / 10, W, H)
        persons = Persons(np.array(boxes, np.float32).reshape(-1, 4),
                          np.full(len(boxes), 0.9, np.float32), info)
        tracker.update(persons, None, k / 10, (W, H), None,
                       feet_bottom_px=np.full(len(boxes), 700.0))
    area = next(iter(tracker.where.areas.values()))
    rows = np.flatnonzero(area.cells.any(axis=1))
    assert (rows.max() + 0.5) * tracker.where.grid.cell_px >= 690


# ------------------------------------------------------------------- the reference's edges


def bench_scene() -> CellScene:
    bench = Block("bench", (-0.4, -0.6, 0.0), (1.4, -0.15, 1.15), occluder=False)
    return CellScene((Walker(((0.0, 0.6, 0.6),)),), (bench,))


def test_the_reference_shows_the_top_edge_of_an_undeclared_bench():
    scene = bench_scene()
    edges = horizontal_edges(scene.reference())
    cam = scene.camera
    # the bench's top back edge, as the camera sees it
    top = cam.project(np.array([[0.5, -0.15, 1.15]]))[0]
    u, v = round(float(top[0])), round(float(top[1]))
    assert edges[v - 2:v + 3, u].any()
    # the plain floor between the bench and the camera has none (only the hazard line)
    front = cam.project(np.array([[0.5, -1.5, 0.0]]))[0]
    assert not edges[int(front[1]) - 3:int(front[1]) + 3, int(front[0])].any()


def test_noise_and_a_dimmer_light_keep_the_same_edges():
    scene = bench_scene()
    ref = scene.reference()
    rng = np.random.default_rng(0)
    noisy = np.clip(ref * 0.7 + rng.normal(0, 2.0, ref.shape), 0, 255).astype(np.uint8)
    a, b = horizontal_edges(ref), horizontal_edges(noisy)
    # a 0.7 light keeps the strong edges; noise adds no long run
    assert (a & b).sum() >= 0.7 * a.sum()
    assert (b & ~a).sum() <= 0.05 * b.sum()


def test_a_box_ending_on_the_bench_top_is_placed_into_the_zone_only_with_the_reference():
    scene = bench_scene()
    cell = zn.parse_cell(zone_data(scene) | {"zones": [
        z for z in zone_data(scene)["zones"] if z["kind"] != "occluder"]})
    model = cell.camera_models["cam0"]
    cam = scene.camera
    # the person at (0.6, 0.6) seen down to the bench top: the box the synthetic model gives
    box = np.array([[319.0, 105.0, 395.0, 181.0]])
    band = (0.0, 27.7)
    plain = occ.place_persons(box, model, cam.width, cam.height, band_px=band)
    columns = occ.OccluderColumns.of_mask(horizontal_edges(scene.reference()))
    seen = occ.place_persons(box, model, cam.width, cam.height, band_px=band,
                             edge_columns=columns)
    assert not plain.hidden[0] and seen.hidden[0]
    # the true feet (0.6, 0.6) lie within the range now, not before
    def on_range(p, near, far):
        d = far - near
        t = np.clip(np.dot(p - near, d) / max(np.dot(d, d), 1e-12), 0, 1)
        return float(np.hypot(*(near + t * d - p)))

    truth = np.array([0.6, 0.6])
    assert on_range(truth, seen.near_m[0], seen.far_m[0]) < 0.3
    assert on_range(truth, plain.near_m[0], plain.far_m[0]) > 1.0


@pytest.mark.parametrize("fraction, hidden", [(0.05, False), (0.4, True)])
def test_the_floor_right_behind_a_1_m_bench_hides_a_crouching_person(fraction, hidden):
    from monitor.zones.visibility import hidden_feet

    scene = CellScene((), (Block("bench", (-0.4, -0.6, 0.0), (1.4, -0.15, 1.0)),))
    cell = zn.parse_cell(zone_data(scene) | {"person": {"crouching_height_m": 1.0}})
    model = cell.camera_models["cam0"]
    px, _ = model.project(np.array([[0.7, 0.05, 0.0]]))
    got = hidden_feet(px, (640, 360), model, cell.spec, cell.meshes, fraction=fraction)
    assert bool(got[0]) is hidden


# ------------------------------------------------------------------- the walk test


def _walk(detector, declare: bool):
    import dataclasses

    from monitor.commission.cut_feet import hidden_feet_doubts, walk_passes_hidden_feet
    from monitor.commission.floor import zone_floors
    from monitor.commission.walk import WalkRecorder, analyse
    from monitor.pipeline import Pipeline
    from monitor.policy import PolicyConfig
    from monitor.replay import scenarios as sc

    s = dataclasses.replace(sc.select(["bench-inside-undeclared"], 2.0)[0],
                            declare_occluders=declare)
    cell = zn.parse_cell(s.zone_data())
    cam = s.scene.camera
    refs = {cam.camera_id: s.scene.reference()}
    pipe = Pipeline(detector, cam.camera_id, PolicyConfig(), cell, references=refs)
    recorder = WalkRecorder(cell, refs, (0.0, detector.foot_uncertainty_px(cam.width,
                                                                            cam.height)))
    for k, (img, truth) in enumerate(s.scene.frames()):
        recorder(pipe.process(img, FrameInfo(cam.camera_id, k, truth.time_s, cam.width,
                                             cam.height), truth.time_s))
    result = analyse(recorder.samples, zone_floors(cell))
    return result, walk_passes_hidden_feet(result.zones), hidden_feet_doubts(result.to_dict())


def test_the_walk_lists_where_an_undeclared_bench_hid_the_walkers_feet(detector):
    result, passes, doubts = _walk(detector, declare=False)
    assert result.zone("robot-protective").feet_hidden, result.to_dict()
    assert not passes
    assert len(doubts) == 1 and "robot-protective" in doubts[0] \
        and "declare an occluder" in doubts[0]


def test_with_the_bench_declared_the_walk_lists_nothing(detector):
    result, passes, doubts = _walk(detector, declare=True)
    assert not any(z.feet_hidden for z in result.zones)
    assert passes and not doubts
