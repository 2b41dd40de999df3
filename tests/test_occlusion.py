"""Placement from the whole box, occluders and shadows: hand-made geometry, no detector.

The camera is the demo camera (cam0, 1280x720 at (0, -6, 3.2) m looking at (0, 0, 0.8) m); the
protective box is the demo's 2 x 2 m square around the robot, the warning area 5 x 5 m.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
import shapely

from monitor import geometry as geo
from monitor import zones as zn
from monitor.geometry import occlusion as occ
from monitor.scene import DEMO_CAMERA
from monitor.types import ZoneHit, ZoneReport

DEMO = Path(__file__).resolve().parents[1] / "zones" / "demo-cell.yaml"
PERSON_M = 1.75


def demo_data() -> dict:
    return copy.deepcopy(zn.read_cell_data(DEMO))


def with_bench(data: dict, height_m: float, y=(-1.6, -1.05), x=(-1.2, 1.2), kind="occluder",
               zone_id="bench", unobserved_ok: bool = True) -> dict:
    """The demo cell with a bench (or cabinet). A bench above the minimum person height hides a
    crouching person right behind it from the one camera: the zone file must accept that
    explicitly (``unobserved_ok``) or it is refused (tests/test_coverage.py)."""
    data["zones"].append({"id": zone_id, "kind": kind, "shape": "box",
                          "min_m": [x[0], y[0], 0.0], "max_m": [x[1], y[1], height_m]})
    if unobserved_ok:
        for z in data["zones"]:
            if z["id"] in ("robot-protective", "robot-warning"):
                z["unobserved_ok"] = True
    return data


def seen_box(x: float, y: float, height_m: float = PERSON_M, bench=None) -> np.ndarray:
    """The box a perfect detector gives for a person at (x, y): head to feet, or head to the
    top of the bench's outline where the bench hides the legs."""
    feet, head = DEMO_CAMERA.project(np.array([[x, y, 0.0], [x, y, height_m]]))
    half = 0.2 * (feet[1] - head[1])
    bottom = feet[1]
    if bench is not None:
        (x0, y0, _), (x1, y1, z1) = bench
        corners = np.array([[a, b, z1] for a in (x0, x1) for b in (y0, y1)])
        bottom = min(bottom, DEMO_CAMERA.project(corners)[:, 1].min())
    return np.array([[feet[0] - half, head[1], feet[0] + half, bottom]])


# ------------------------------------------------------------------------ legs hidden


@pytest.mark.parametrize("bench_m", [0.8, 0.95, 1.15, 1.3])
@pytest.mark.parametrize("spot", [(0.0, -0.6), (0.6, -0.3), (-0.7, 0.5)])
def test_person_behind_a_bench_inside_the_protective_zone_is_found(bench_m, spot):
    cell = zn.parse_cell(with_bench(demo_data(), bench_m))
    bench = ((-1.2, -1.6, 0.0), (1.2, -1.05, bench_m))
    box = seen_box(*spot, bench=bench)
    rep = zn.check_persons(cell, "cam0", box)
    got = {h.zone_id for h in rep.hits}
    assert {"robot-protective", "cam0-protective"} <= got, (bench_m, spot, got)


def test_without_the_occluder_the_bottom_anchor_puts_the_bench_case_in_the_warning_zone():
    # the failure of the issue, kept as a test of the test: the same box, no occluder declared
    bench = ((-1.2, -1.6, 0.0), (1.2, -1.05, 1.15))
    box = seen_box(0.0, -0.6, bench=bench)
    # a robot base too small to matter: the default one would catch this box by chance (its
    # bottom, on the bench top, lies on the base's image outline)
    tiny_base = demo_data() | {"robot_base": {"radius_m": 0.05, "height_m": 0.05}}
    plain = zn.check_persons(zn.parse_cell(tiny_base), "cam0", box)
    assert "robot-protective" not in {h.zone_id for h in plain.hits}
    declared = zn.check_persons(zn.parse_cell(with_bench(demo_data(), 1.15)), "cam0", box)
    assert "robot-protective" in {h.zone_id for h in declared.hits}


def test_placement_range_holds_the_true_position_for_every_height_in_range():
    cell = zn.parse_cell(with_bench(demo_data(), 1.15))
    model = cell.camera_models["cam0"]
    prep = cell.prepared
    for h in (1.0, 1.3, 1.75, 2.0):
        box = seen_box(0.3, -0.4, height_m=h, bench=((-1.2, -1.6, 0), (1.2, -1.05, 1.15)))
        p = occ.place_persons(box, model, 1280, 720, height_range_m=(1.0, 2.0),
                              occluder_outlines_px=prep.occluder_outlines["cam0"])
        assert p.hidden[0] and p.located[0]
        seg = shapely.LineString([p.near_m[0], p.far_m[0]])
        assert seg.distance(shapely.Point(0.3, -0.4)) < 0.05, (h, p.near_m, p.far_m)


def test_person_in_clear_view_keeps_a_tight_answer():
    cell = zn.load_cell(DEMO)
    model = cell.camera_models["cam0"]
    box = seen_box(0.0, -2.0)
    p = occ.place_persons(box, model, 1280, 720, band_px=(0.0, 0.0))
    assert not p.hidden[0]
    np.testing.assert_allclose(p.near_m[0], [0.0, -2.0], atol=0.01)
    assert p.length_m[0] < 1e-6
    rep = zn.check_persons(cell, "cam0", box)
    assert {h.zone_id for h in rep.hits} == {"robot-warning", "cam0-warning"}


def test_one_box_over_two_persons_one_behind_the_other_finds_the_one_behind():
    # a person inside the protective zone, another in front of them outside it: the merged
    # box runs from the far person's head to the near person's feet. The bottom alone puts
    # "the person" outside; the box is too tall for one person there, so the far one counts.
    cell = zn.load_cell(DEMO)
    far, near = seen_box(0.0, -0.3), seen_box(0.0, -2.4)
    merged = np.array([[min(far[0, 0], near[0, 0]), far[0, 1],
                        max(far[0, 2], near[0, 2]), near[0, 3]]])
    alone = zn.check_persons(cell, "cam0", near)
    assert "robot-protective" not in {h.zone_id for h in alone.hits}
    rep = zn.check_persons(cell, "cam0", merged)
    assert {"robot-protective", "cam0-protective"} <= {h.zone_id for h in rep.hits}
    p = occ.place_persons(merged, cell.camera_models["cam0"], 1280, 720)
    seg = shapely.LineString([p.near_m[0], p.far_m[0]])
    assert seg.distance(shapely.Point(0.0, -0.3)) < 0.05, (p.near_m, p.far_m)


def test_feet_band_sweeps_between_its_ends():
    cell = zn.load_cell(DEMO)
    model = cell.camera_models["cam0"]
    box = seen_box(0.0, -2.0)
    box[0, 3] += 40.0  # the detector's box reaches 40 px below the feet
    p = occ.place_persons(box, model, 1280, 720, band_px=(0.0, 49.0))
    assert not p.hidden[0]
    seg = shapely.LineString([p.near_m[0], p.far_m[0]])
    assert seg.distance(shapely.Point(0.0, -2.0)) < 1e-6
    assert p.feet_top_px[0] < p.feet_bottom_px[0]


def test_box_cut_by_the_image_bottom_is_placed_from_the_head():
    cell = zn.load_cell(DEMO)
    model = cell.camera_models["cam0"]
    # a person so near the camera that the feet are below the image
    feet, head = DEMO_CAMERA.project(np.array([[0.0, -3.6, 0.0], [0.0, -3.6, PERSON_M]]))
    assert feet[1] > 720
    box = np.array([[feet[0] - 60, head[1], feet[0] + 60, 720.0]])
    p = occ.place_persons(box, model, 1280, 720)
    assert p.hidden[0] and p.located[0]
    seg = shapely.LineString([p.near_m[0], p.far_m[0]])
    assert seg.distance(shapely.Point(0.0, -3.6)) < 0.05


def test_crouching_person_behind_a_crate_is_found_from_the_head():
    data = with_bench(demo_data(), 0.7, y=(-1.45, -1.05), x=(-0.4, 0.4), zone_id="crate")
    cell = zn.parse_cell(data)
    box = seen_box(0.0, -0.8, height_m=1.0, bench=((-0.4, -1.45, 0), (0.4, -1.05, 0.7)))
    rep = zn.check_persons(cell, "cam0", box)
    assert "robot-protective" in {h.zone_id for h in rep.hits}


def test_short_box_without_a_declared_occluder_counts_as_hidden():
    cell = zn.load_cell(DEMO)
    model = cell.camera_models["cam0"]
    # only the upper 60 cm of a person at (0, -0.5) shows: nothing declared hides it
    feet, head = DEMO_CAMERA.project(np.array([[0.0, -0.5, 0.0], [0.0, -0.5, PERSON_M]]))
    cut = DEMO_CAMERA.project(np.array([[0.0, -0.5, PERSON_M - 0.6]]))[0]
    box = np.array([[feet[0] - 30, head[1], feet[0] + 30, cut[1]]])
    hidden = occ.feet_may_be_hidden(box, model, 1280, 720, min_height_m=1.0)
    assert hidden[0]
    rep = zn.check_persons(cell, "cam0", box)
    assert "robot-protective" in {h.zone_id for h in rep.hits}
    # the whole person is not short
    whole = np.array([[feet[0] - 30, head[1], feet[0] + 30, feet[1]]])
    assert not occ.feet_may_be_hidden(whole, model, 1280, 720, min_height_m=1.0)[0]


def test_image_zone_counts_the_whole_feet_range():
    cell = zn.parse_cell(with_bench(demo_data(), 1.15))
    box = seen_box(0.0, -0.6, bench=((-1.2, -1.6, 0), (1.2, -1.05, 1.15)))
    rep = zn.check_persons(cell, "cam0", box)
    assert "cam0-protective" in {h.zone_id for h in rep.hits}


@pytest.mark.parametrize("seed", range(3))
def test_vertical_segments_agree_with_shapely(seed):
    rng = np.random.default_rng(seed)
    polys = [np.array([[100, 100], [400, 120], [350, 400], [150, 300]], float),
             np.array([[500, 50], [700, 50], [700, 60], [500, 60]], float),
             np.array([[200, 500], [260, 420], [320, 500], [260, 460]], float)]
    edges = occ.PolygonSegments.build(polys)
    n = 400
    u = rng.uniform(0, 800, n)
    u[:20] = 500.0  # on a vertical edge
    y0 = rng.uniform(0, 600, n)
    y1 = y0 + rng.uniform(0, 200, n)
    got = occ.segments_hit_polygons(u, y0, y1, edges)
    for i in range(n):
        seg = shapely.LineString([(u[i], y0[i]), (u[i], y1[i])])
        for k, p in enumerate(polys):
            want = shapely.Polygon(p).intersects(seg)
            assert got[i, k] == want, (i, k, u[i], y0[i], y1[i])


# ------------------------------------------------------------------------ clear view


@pytest.mark.parametrize("where", [(0.0, -2.45), (-2.45, 0.0), (2.45, 0.5)])
def test_person_in_clear_view_more_than_1_m_outside_gets_no_protective_hit(where):
    cell = zn.load_cell(DEMO)
    rep = zn.check_persons(cell, "cam0", seen_box(*where))
    assert "robot-protective" not in {h.zone_id for h in rep.hits}


# ------------------------------------------------------------------------ shadows


def test_shadow_of_a_cabinet_hides_a_crouching_person_behind_it():
    data = with_bench(demo_data(), 2.2, y=(-2.0, -1.6), x=(-0.5, 0.5), zone_id="cabinet")
    cell = zn.parse_cell(data)
    pts = np.array([[0.0, -1.2], [0.0, 0.9], [0.0, -2.5], [2.0, -1.2], [1.5, 0.5]])
    got = occ.shadow_mask(cell, "cam0", pts)
    assert got.tolist() == [True, True, False, False, False]


def test_validate_refuses_protective_floor_no_camera_sees_behind_a_cabinet():
    data = with_bench(demo_data(), 2.2, y=(-2.0, -1.6), x=(-0.5, 0.5), zone_id="cabinet",
                      unobserved_ok=False)
    errors, warnings = zn.cell_faults(data, DEMO)
    assert any("robot-protective" in e and "seen by no camera" in e for e in errors), errors
    assert any("robot-warning" in w and "seen by no camera" in w for w in warnings), warnings
    data = with_bench(demo_data(), 2.2, y=(-2.0, -1.6), x=(-0.5, 0.5), zone_id="cabinet")
    errors, warnings = zn.cell_faults(data, DEMO)
    assert not errors
    assert any("robot-protective" in w and "unobserved_ok" in w for w in warnings), warnings
    errors, warnings = zn.cell_faults(demo_data(), DEMO)
    assert not errors and not any("seen by no camera" in w for w in warnings)


def test_occluder_must_be_a_volume():
    data = demo_data()
    data["zones"].append({"id": "oops", "kind": "occluder", "shape": "polygon",
                          "camera": "cam0", "points_px": [[0, 0], [10, 0], [10, 10]]})
    errors, _ = zn.cell_faults(data, DEMO)
    assert any("oops" in e and "occluder is a cell volume" in e for e in errors)


def test_occluder_is_not_a_zone_that_stops():
    cell = zn.parse_cell(with_bench(demo_data(), 1.15))
    rep = zn.check_persons(cell, "cam0", seen_box(0.0, -1.3))  # standing in the bench
    assert "bench" not in {h.zone_id for h in rep.hits}


# ------------------------------------------------------------------------ merging


def test_merge_takes_the_lowest_separation_scale_and_keeps_lost_holds():
    a = ZoneReport(hits=(ZoneHit("P", "protective", 0, 0.0, 0.0, track_id=3),),
                   separation_speed_scale=0.6)
    b = ZoneReport(hits=(ZoneHit("P", "protective", 0, 0.0, None, track_id=3, lost=True,
                                 lost_since=1.5),), separation_speed_scale=0.2)
    m = zn.merge_towards_danger(a, b)
    assert m.separation_speed_scale == 0.2
    (hit,) = m.hits
    assert hit.lost and hit.track_id == 3 and hit.lost_since == 1.5
    assert zn.merge_towards_danger(b, a).hits == m.hits
    c = ZoneReport(separation_speed_scale=math.nan)
    assert math.isnan(zn.merge_towards_danger(a, c).separation_speed_scale)
    assert zn.merge_towards_danger(ZoneReport(), ZoneReport()).separation_speed_scale is None


def test_non_finite_box_is_an_input_error():
    from monitor.errors import InputError

    with pytest.raises(InputError, match="non-finite"):
        zn.check_persons(zn.load_cell(DEMO), "cam0", np.array([[0, 0, np.nan, 10]]))


def test_preview_draws_the_shadow_behind_an_occluder():
    data = with_bench(demo_data(), 2.2, y=(-2.0, -1.6), x=(-0.5, 0.5), zone_id="cabinet")
    cell = zn.parse_cell(data)
    from monitor.zones.draw import shadow_image

    mask = shadow_image(cell, "cam0", 1280, 720)
    # the floor just behind the cabinet, and not the floor in front of it
    behind = DEMO_CAMERA.project(np.array([[0.0, -1.2, 0.0]]))[0]
    front = DEMO_CAMERA.project(np.array([[0.0, -2.5, 0.0]]))[0]
    assert mask[int(behind[1]), int(behind[0])]
    assert not mask[int(front[1]), int(front[0])]
    plain = shadow_image(zn.load_cell(DEMO), "cam0", 1280, 720)  # the robot base only
    assert not plain[int(behind[1]), int(behind[0])]
    frame = np.full((720, 1280, 3), 128, np.uint8)
    drawn = zn.draw_zones(frame, cell, "cam0")
    assert not np.array_equal(drawn[int(behind[1]), int(behind[0])],
                              zn.draw_zones(frame, zn.load_cell(DEMO), "cam0")[
                                  int(behind[1]), int(behind[0])])


# ------------------------------------------------------------------------ foot band


def test_detector_default_foot_band_is_the_measured_one():
    from monitor.detector import DetectorConfig

    assert DetectorConfig().foot_uncertainty_cells == occ.SYNTHETIC_FOOT_BAND_CELLS[1]


@pytest.mark.slow
def test_synthetic_model_box_bottom_lies_within_one_cell_below_the_feet(detector):
    from monitor.scene import DemoScene
    from monitor.types import FrameInfo

    cell_px = detector.foot_uncertainty_px(1280, 720) / detector.config.foot_uncertainty_cells
    errors = []
    scene = DemoScene(fps=1.0)
    for img, truth in scene.frames():
        if len(truth.persons) != 1 or truth.persons[0].visible_fraction < 0.99:
            continue
        if truth.persons[0].full_box_px[3] >= 715:
            continue
        det = detector.detect_timed(img, FrameInfo("cam0", truth.index, 0.0, 1280, 720))
        if len(det.persons) == 1:
            errors.append(float(det.persons.boxes_px[0, 3]) - truth.persons[0].full_box_px[3])
    assert len(errors) >= 5
    lo, hi = occ.SYNTHETIC_FOOT_BAND_CELLS
    assert lo * cell_px - 1 <= min(errors) and max(errors) <= hi * cell_px + 1, errors


def test_box_cut_at_both_image_edges_reaches_as_far_as_the_bottom_allows():
    # a camera at 1.4 m looking almost level, a tall person 1.2 m in front of it: head above
    # the image, feet below it
    k = np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]])
    r, t = geo.look_at((0.0, -6.0, 1.4), (0.0, 0.0, 1.2))
    model = geo.CameraModel.pinhole(1280, 720, k, None, r, t)
    px, _ = model.project(np.array([[0.3, -4.8, 0.0], [0.3, -4.8, 2.0]]))
    (fu, fv), (_, hv) = px
    assert hv < 0 and fv > 720
    box = np.array([[fu - 150, 0.0, fu + 150, 720.0]])
    p = occ.place_persons(box, model, 1280, 720)
    seg = shapely.LineString([p.near_m[0], p.far_m[0]])
    assert p.located[0] and seg.distance(shapely.Point(0.3, -4.8)) < 0.05


def test_fast_projection_equals_opencv():
    model = zn.load_cell(DEMO).camera_models["cam0"]
    pts = np.random.default_rng(0).uniform([-4, -4, 0], [4, 4, 2.5], (50, 3))
    got, front = occ.project_px(model, pts)
    want, want_front = model.project(pts)
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert (front == want_front).all()


def test_the_zone_drawing_cache_keeps_the_shadow_of_the_cell_it_was_given():
    # a zone swap brings a new Cell: its shadow, never the old one, even at the same size
    from monitor.zones.draw import ZoneDrawCache, shadow_image

    bench = zn.parse_cell(with_bench(demo_data(), 2.2, y=(-2.0, -1.6), x=(-0.5, 0.5),
                                     zone_id="cabinet"))
    plain = zn.load_cell(DEMO)
    cache = ZoneDrawCache()
    first = cache.shadow(bench, "cam0", 640, 360)
    assert cache.shadow(bench, "cam0", 640, 360) is first  # kept between frames
    assert np.array_equal(first, shadow_image(bench, "cam0", 640, 360))
    assert np.array_equal(cache.shadow(plain, "cam0", 640, 360),
                          shadow_image(plain, "cam0", 640, 360))
    assert not np.array_equal(cache.shadow(plain, "cam0", 640, 360), first)
    assert cache.shadow(bench, "cam0", 320, 180).shape == (180, 320)
