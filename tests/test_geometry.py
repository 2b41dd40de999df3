"""Geometry: point-in-polygon against shapely, polygon faults, homography, camera model,
FCL distances against closed forms, ISO/TS 15066 arithmetic, tool pose."""

from __future__ import annotations

import math

import fcl
import numpy as np
import pytest
import shapely
import trimesh
from shapely.geometry import Point, Polygon

from monitor import geometry as geo

# ---------------------------------------------------------------------------- factories


def star_polygon(rng: np.random.Generator, k: int, centre=(0.0, 0.0), r_min=0.2, r_max=1.0
                 ) -> np.ndarray:
    """A random simple (star-shaped, usually non-convex) polygon."""
    angles = np.sort(rng.uniform(0, 2 * np.pi, k))
    radii = rng.uniform(r_min, r_max, k)
    return np.c_[centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles)]


def demo_camera(distortion=None) -> geo.CameraModel:
    k = np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]])
    r, t = geo.look_at((0, -6.0, 3.2), (0, 0, 0.8))
    return geo.CameraModel.pinhole(1280, 720, k, distortion, r, t)


# ---------------------------------------------------------------------------- polygons


@pytest.mark.parametrize("seed", range(8))
def test_point_in_polygon_agrees_with_shapely(seed):
    rng = np.random.default_rng(seed)
    poly = star_polygon(rng, int(rng.integers(3, 25)))
    if seed % 2:
        poly = poly[::-1]  # clockwise as well
    pts = rng.uniform(-1.1, 1.1, size=(4000, 2))
    ref_poly = Polygon(poly)
    ref = shapely.contains_xy(ref_poly, pts[:, 0], pts[:, 1])
    ours = geo.points_in_polygon(pts, poly)
    # points within 1e-9 of the boundary may go either way
    far = shapely.distance(ref_poly.exterior, shapely.points(pts)) > 1e-9
    assert ref.sum() > 100  # the test sees both outcomes
    np.testing.assert_array_equal(ours[far], ref[far])


def test_points_in_polygons_batch_equals_one_by_one():
    rng = np.random.default_rng(42)
    polys = [star_polygon(rng, int(rng.integers(3, 12)), centre=rng.uniform(-2, 2, 2))
             for _ in range(7)]
    pts = rng.uniform(-3, 3, size=(500, 2))
    batch = geo.points_in_polygons(pts, polys)
    assert batch.shape == (500, 7)
    for k, p in enumerate(polys):
        np.testing.assert_array_equal(batch[:, k], geo.points_in_polygon(pts, p))


@pytest.mark.parametrize(
    "points, fragment",
    [
        pytest.param([[0, 0], [10, 0]], "at least 3 points", id="two-points"),
        pytest.param([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], "do not close", id="closed"),
        pytest.param([[0, 0], [10, 0], [10, 0], [0, 10]], "repeats", id="repeated"),
        pytest.param([[0, 0], [5, 0], [10, 0]], "one line", id="collinear"),
        pytest.param([[0, 0], [10, 10], [10, 0], [0, 10]], "self-intersecting", id="bowtie"),
        pytest.param([[0, 0], [10, 0], [10, 10], [5, 0]], "self-intersecting", id="touching"),
        pytest.param([[0, 0], [10, 0], [10, 10], [0, 10], [20, 10]], "self-intersecting",
                     id="spike"),
    ],
)
def test_polygon_fault_names_the_fault(points, fragment):
    fault = geo.polygon_fault(points)
    assert fault is not None and fragment in fault


@pytest.mark.parametrize("seed", range(4))
def test_polygon_validity_agrees_with_shapely(seed):
    rng = np.random.default_rng(100 + seed)
    agree = 0
    invalid = 0
    for _ in range(300):
        p = rng.uniform(0, 100, size=(int(rng.integers(4, 9)), 2))
        ours_ok = geo.polygon_fault(p) is None
        ref_ok = Polygon(p).is_valid
        assert ours_ok == ref_ok, p.tolist()
        agree += 1
        invalid += not ref_ok
    assert 0 < invalid < agree  # both kinds were seen


@pytest.mark.parametrize("seed", range(5))
def test_triangulation_covers_the_polygon(seed):
    rng = np.random.default_rng(seed)
    poly = star_polygon(rng, int(rng.integers(4, 20)))
    tris = geo.triangulate_polygon(poly)
    assert len(tris) == len(poly) - 2
    areas = [geo.polygon_signed_area(poly[t]) for t in tris]
    assert min(areas) > 0  # all counter-clockwise, none flipped
    assert sum(areas) == pytest.approx(abs(geo.polygon_signed_area(poly)), rel=1e-9)


def test_clip_polygon_to_rect_matches_shapely():
    poly = np.array([[-50, 100], [700, -30], [1400, 500], [300, 900]], float)
    clipped = geo.clip_polygon_to_rect(poly, 1280, 720)
    ref = Polygon(poly).intersection(shapely.box(0, 0, 1280, 720))
    assert abs(geo.polygon_signed_area(clipped)) == pytest.approx(ref.area, rel=1e-9)
    assert clipped[:, 0].min() >= 0 and clipped[:, 0].max() <= 1280
    assert clipped[:, 1].min() >= 0 and clipped[:, 1].max() <= 720


# ---------------------------------------------------------------------------- homography


def test_homography_round_trip_exact_pairs():
    cam = demo_camera()
    rng = np.random.default_rng(3)
    floor = rng.uniform(-3, 3, size=(12, 2))
    px, front = cam.project(np.c_[floor, np.zeros(len(floor))])
    assert front.all()
    h = geo.fit_homography(px, floor)
    to_floor, _ = geo.apply_homography(h, px)
    assert np.abs(to_floor - floor).max() < 1e-6  # metres
    assert geo.reprojection_errors_px(h, px, floor).max() < 1e-6  # pixels
    # unseen points too
    test = rng.uniform(-3, 3, size=(50, 2))
    tpx, _ = cam.project(np.c_[test, np.zeros(50)])
    back, _ = geo.apply_homography(h, tpx)
    assert np.abs(back - test).max() < 1e-6


def test_homography_with_pixel_noise_reprojects_within_2px():
    cam = demo_camera()
    rng = np.random.default_rng(4)
    floor = rng.uniform(-3, 3, size=(30, 2))
    px, _ = cam.project(np.c_[floor, np.zeros(30)])
    noisy = px + rng.normal(0, 0.7, size=px.shape)
    h = geo.fit_homography(noisy, floor)
    err = geo.reprojection_errors_px(h, noisy, floor)
    assert math.sqrt(np.mean(err**2)) < 2.0
    # and the fitted map stays close to the true one
    true_px, _ = cam.project(np.array([[0.5, 0.5, 0.0]]))
    est, _ = geo.apply_homography(h, true_px)
    assert np.linalg.norm(est[0] - [0.5, 0.5]) < 0.02


@pytest.mark.parametrize(
    "img, floor, fragment",
    [
        pytest.param([[0, 0], [100, 0], [0, 100]], [[0, 0], [1, 0], [0, 1]], "at least 4",
                     id="three-pairs"),
        pytest.param([[0, 0], [100, 0], [200, 0], [0, 100]], [[0, 0], [1, 0], [2, 0], [0, 1]],
                     "degenerate", id="three-collinear"),
        pytest.param([[0, 0], [100, 0], [200, 0], [300, 0]], [[0, 0], [1, 0], [2, 0], [3, 0]],
                     "degenerate", id="all-collinear"),
        pytest.param([[0, 0], [100, 0], [100, 100], [0, 100]], [[0, 0], [1, 0], [2, 0], [3, 0]],
                     "degenerate", id="floor-on-a-line"),
    ],
)
def test_degenerate_homography_is_refused(img, floor, fragment):
    with pytest.raises(geo.GeometryError, match=fragment):
        geo.fit_homography(np.array(img, float), np.array(floor, float))


# ---------------------------------------------------------------------------- camera model


def test_look_at_puts_the_target_on_the_principal_point():
    cam = demo_camera()
    px, front = cam.project(np.array([[0.0, 0.0, 0.8]]))
    assert front[0]
    np.testing.assert_allclose(px[0], [640, 360], atol=1e-9)
    centre = -cam.rotation.T @ cam.translation_m
    np.testing.assert_allclose(centre, [0, -6.0, 3.2], atol=1e-12)


@pytest.mark.parametrize("distortion", [None, [-0.12, 0.03, 0.001, -0.0005, 0.0]],
                         ids=["pinhole", "distorted"])
def test_pixel_to_floor_inverts_projection(distortion):
    cam = demo_camera(None if distortion is None else np.array(distortion))
    rng = np.random.default_rng(5)
    floor = rng.uniform(-2.5, 2.5, size=(100, 2))
    px, _ = cam.project(np.c_[floor, np.zeros(100)])
    back, valid = cam.pixel_to_floor(px)
    assert valid.all()
    assert np.abs(back - floor).max() < 1e-4


def test_pixels_above_the_horizon_are_invalid():
    k = np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]])
    r, t = geo.look_at((0, -6.0, 1.5), (0, 0, 1.5))  # horizontal: horizon at row 360
    cam = geo.CameraModel.pinhole(1280, 720, k, None, r, t)
    _, valid = cam.pixel_to_floor(np.array([[640, 300], [640, 420]]))
    assert valid.tolist() == [False, True]


def pitched_camera(height_m: float, pitch_deg: float, roll_deg: float = 0.0,
                   yaw_deg: float = 0.0) -> tuple[geo.CameraModel, np.ndarray, np.ndarray]:
    """A camera at (0, 0, height) looking along +y, pitched up by ``pitch_deg`` (negative:
    down), then rolled about its axis and turned about the vertical. Returns it, K and R."""
    k = np.array([[800.0, 0, 640], [0, 800.0, 360], [0, 0, 1]])
    p = math.radians(pitch_deg)
    fwd = np.array([0.0, math.cos(p), math.sin(p)])
    right = np.array([1.0, 0.0, 0.0])
    down = np.cross(fwd, right)
    r = np.stack([right, down, fwd])  # cell -> camera
    roll = geo.rpy_to_matrix(0, 0, roll_deg)  # about the camera's z (forward) axis
    r = roll @ r @ geo.rpy_to_matrix(0, 0, -yaw_deg)
    eye = np.array([0.0, 0.0, height_m])
    return geo.CameraModel.pinhole(1280, 720, k, None, r, -r @ eye), k, r


@pytest.mark.parametrize("pitch", [-60, -45, -20, -5, 0, 5, 20, 30, 40])
@pytest.mark.parametrize("height", [1.0, 2.5, 4.0])
def test_pixel_to_floor_validity_agrees_with_a_ray_plane_reference(pitch, height):
    """Cameras tilted up used to get made-up floor points in the sky and none on the floor."""
    rng = np.random.default_rng(int(height * 100 + pitch + 1000))
    roll, yaw = rng.uniform(-15, 15), rng.uniform(-180, 180)
    cam, k, r = pitched_camera(height, pitch, roll, yaw)
    px = np.c_[rng.uniform(0, 1280, 3000), rng.uniform(0, 720, 3000)]
    rays = (np.linalg.inv(k) @ np.c_[px, np.ones(len(px))].T).T @ r  # R^T d, cell frame
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    clear = np.abs(rays[:, 2]) > 1e-6  # rays grazing the horizon may go either way
    ref_valid = rays[:, 2] < 0
    xy, valid = cam.pixel_to_floor(px)
    np.testing.assert_array_equal(valid[clear], ref_valid[clear])
    hit = ref_valid & clear & (rays[:, 2] < -0.05)
    s = height / -rays[hit, 2]
    ref_xy = np.array([0.0, 0.0]) + s[:, None] * rays[hit, :2]
    np.testing.assert_allclose(xy[hit], ref_xy, rtol=1e-7, atol=1e-7 * height)
    row = cam.horizon_row_px()
    if row is not None and 0 < row < 720 and abs(roll) < 1e-9:
        assert valid[px[:, 1] > row + 1].all()


@pytest.mark.parametrize("pitch", [20, 30, 40])
def test_horizon_row_of_an_upward_camera(pitch):
    cam, _, _ = pitched_camera(2.0, pitch)
    # a level-rolled camera pitched up by p sees the horizon p degrees below the centre row
    expected = 360 + 800 * math.tan(math.radians(pitch))
    assert cam.horizon_row_px() == pytest.approx(expected, rel=1e-9)
    assert cam.floor_is_below_horizon()
    _, valid = cam.pixel_to_floor(np.array([[640, expected - 5], [640, expected + 5]]))
    assert valid.tolist() == [False, True]


# ---------------------------------------------------------------------------- FCL vs closed forms


def _interval_gap(a0, a1, b0, b1):
    return max(0.0, b0 - a1, a0 - b1)


def _rect_distance(p, lo, hi):
    d = np.maximum(np.maximum(lo - p, p - hi), 0.0)
    return float(np.hypot(*d))


@pytest.mark.parametrize("seed", range(3))
def test_fcl_cylinder_to_box_distance_matches_closed_form(seed):
    rng = np.random.default_rng(seed)
    checked = 0
    for _ in range(150):
        lo = rng.uniform(-2, 0, 3)
        hi = lo + rng.uniform(0.2, 2, 3)
        yaw = rng.uniform(-180, 180)
        box = geo.fcl_box(lo, hi, yaw)
        r, h = rng.uniform(0.1, 0.5), rng.uniform(0.5, 2)
        c = rng.uniform(-4, 4, 3)
        cyl = geo.fcl_vertical_cylinder(c[:2], r, c[2], c[2] + h)
        # closed form: vertical cylinder and vertical box separate into xy and z parts
        centre = (lo + hi) / 2
        rot = geo.rpy_to_matrix(0, 0, yaw)[:2, :2]
        local = rot.T @ (c[:2] - centre[:2])
        half = (hi - lo)[:2] / 2
        dxy = max(0.0, _rect_distance(local, -half, half) - r)
        dz = _interval_gap(c[2], c[2] + h, lo[2], hi[2])
        expected = math.hypot(dxy, dz)
        got = fcl.distance(cyl, box)
        if expected > 1e-3:
            assert got == pytest.approx(expected, abs=1e-3)
            assert not fcl.collide(cyl, box)
            checked += 1
        elif (_rect_distance(local, -half, half) < r - 1e-3
              and min(c[2] + h, hi[2]) - max(c[2], lo[2]) > 1e-3):
            assert fcl.collide(cyl, box)  # clearly overlapping, containment included
    assert checked > 50


@pytest.mark.parametrize("seed", range(3))
def test_fcl_cylinder_to_cylinder_distance_matches_closed_form(seed):
    rng = np.random.default_rng(10 + seed)
    checked = 0
    for _ in range(150):
        c1, c2 = rng.uniform(-3, 3, 3), rng.uniform(-3, 3, 3)
        r1, r2 = rng.uniform(0.05, 0.6, 2)
        h1, h2 = rng.uniform(0.3, 2, 2)
        a = geo.fcl_vertical_cylinder(c1[:2], r1, c1[2], c1[2] + h1)
        b = geo.fcl_vertical_cylinder(c2[:2], r2, c2[2], c2[2] + h2)
        dxy = max(0.0, float(np.hypot(*(c1[:2] - c2[:2]))) - r1 - r2)
        dz = _interval_gap(c1[2], c1[2] + h1, c2[2], c2[2] + h2)
        expected = math.hypot(dxy, dz)
        if expected > 1e-3:
            assert fcl.distance(a, b) == pytest.approx(expected, abs=1e-3)
            checked += 1
    assert checked > 50


def test_person_fully_inside_a_volume_counts_as_overlap():
    box = geo.fcl_box((-2, -2, 0), (2, 2, 3))
    person = geo.fcl_vertical_cylinder((0.3, -0.2), 0.3, 0.0, 1.9)
    assert fcl.collide(person, box)


@pytest.mark.parametrize("seed", range(3))
def test_extruded_non_convex_polygon_overlap_agrees_with_shapely(seed):
    rng = np.random.default_rng(20 + seed)
    poly = star_polygon(rng, 9, r_min=0.5, r_max=2.5)
    parts = geo.fcl_prism_parts(poly, 0.0, 2.0)
    ref = Polygon(poly)
    for _ in range(200):
        x, y = rng.uniform(-3, 3, 2)
        r = 0.3
        d = ref.distance(Point(x, y))
        if abs(d - r) < 1e-3:
            continue
        person = geo.fcl_vertical_cylinder((x, y), r, 0.0, 1.9)
        hit = any(fcl.collide(person, p) for p in parts)
        assert hit == (d < r), (x, y, d)


def test_points_in_mesh_matches_box_bounds():
    mesh = trimesh.creation.box(extents=(2, 3, 1))
    rng = np.random.default_rng(6)
    pts = rng.uniform(-2, 2, size=(500, 3))
    inside = geo.points_in_mesh(pts, mesh.vertices, mesh.faces)
    expected = np.all(np.abs(pts) < np.array([1, 1.5, 0.5]), axis=1)
    np.testing.assert_array_equal(inside, expected)


# ---------------------------------------------------------------------------- ISO/TS 15066


def test_protective_separation_by_hand():
    p = geo.SeparationParams(person_speed_mps=1.6, reaction_time_s=0.1, deceleration_mps2=2.0,
                             intrusion_distance_m=0.2, robot_uncertainty_m=0.02)
    # v_r = 1 m/s: T_s = 0.5, S_h = 1.6 * 0.6, S_r = 0.1, S_s = 0.25, + C + Z_d + Z_r
    expected = 0.96 + 0.1 + 0.25 + 0.2 + 0.1 + 0.02
    assert geo.protective_separation_m(1.0, p, 0.1) == pytest.approx(expected)
    assert geo.protective_separation_m(0.0, p, 0.1) == pytest.approx(0.16 + 0.32)


@pytest.mark.parametrize("d", [2.4, 3.0, 4.0, 6.0])
def test_max_robot_speed_inverts_the_separation(d):
    p = geo.SeparationParams()
    v = geo.max_robot_speed_mps(d, p, 0.1)
    assert v > 0
    assert geo.protective_separation_m(v, p, 0.1) == pytest.approx(d, abs=1e-9)


def test_max_robot_speed_is_zero_when_too_close():
    p = geo.SeparationParams()
    assert geo.max_robot_speed_mps(p.intrusion_distance_m + 0.1 + p.robot_uncertainty_m, p,
                                   0.1) == 0.0
    assert geo.max_robot_speed_mps(0.0, p, 0.1) == 0.0


# ---------------------------------------------------------------------------- tool pose


def test_quaternion_to_matrix_quarter_turn_about_z():
    s = math.sqrt(0.5)
    m = geo.quaternion_to_matrix((0, 0, s, s))
    np.testing.assert_allclose(m @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(geo.quaternion_to_matrix((0, 0, 0, 2.0)), np.eye(3))
    with pytest.raises(geo.GeometryError):
        geo.quaternion_to_matrix((0, 0, 0, 0))


def test_tool_transform_applies_the_tracker_offset():
    offset = geo.rigid(geo.rpy_to_matrix(0, 0, 180), np.array([13.55, 1.82, 49.17]) / 1000)
    s = math.sqrt(0.5)
    pose = geo.ToolPose((1.0, 2.0, 0.5), (0, 0, s, s), time=3.0)  # 90 deg about z
    t = geo.tool_transform(pose, offset)
    # the offset translation is expressed in the tracker frame, turned by the pose
    np.testing.assert_allclose(t[:3, 3], [1.0 - 0.00182, 2.0 + 0.01355, 0.5 + 0.04917],
                               atol=1e-12)
    # 90 deg (pose) + 180 deg (offset) about z: tool x points along cell -y
    np.testing.assert_allclose(t[:3, :3] @ [1, 0, 0], [0, -1, 0], atol=1e-12)
