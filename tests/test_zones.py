"""Zone files: the demo cell, validation faults (message + file unchanged), config hash, atomic
saving, and the per-frame query (image anchors, volumes, masks, tool separation)."""

from __future__ import annotations

import copy
import math
import random
from pathlib import Path

import numpy as np
import pytest
import shapely
import trimesh
import yaml

from monitor import geometry as geo
from monitor import zones as zn
from monitor.errors import ConfigError
from monitor.scene import DEMO_CAMERA
from monitor.zones import separation as zn_separation

DEMO = Path(__file__).resolve().parents[1] / "zones" / "demo-cell.yaml"

# ---------------------------------------------------------------------------- factories

K = [[900.0, 0.0, 640.0], [0.0, 900.0, 360.0], [0.0, 0.0, 1.0]]


def pinhole(eye=(0.0, -6.0, 3.2), target=(0.0, 0.0, 0.8)) -> dict:
    r, t = geo.look_at(eye, target)
    return {"type": "pinhole", "camera_matrix": K, "distortion": [],
            "rotation": r.tolist(), "translation_m": t.tolist()}


def base_data() -> dict:
    """A small valid cell: one calibrated camera, one zone of each shape family."""
    return {
        "version": 1,
        "name": "test",
        "cameras": [{"id": "cam0", "width": 1280, "height": 720, "calibration": pinhole()}],
        "zones": [
            {"id": "img-stop", "kind": "protective", "shape": "polygon", "camera": "cam0",
             "points_px": [[100, 100], [400, 100], [400, 400], [100, 400]]},
            {"id": "vol-slow", "kind": "warning", "speed_scale": 0.3, "shape": "extrude",
             "points_m": [[-2, -2], [2, -2], [2, 2], [-2, 2]], "z_min_m": 0, "z_max_m": 2},
            {"id": "vol-stop", "kind": "protective", "shape": "box",
             "min_m": [-1, -1, 0], "max_m": [1, 1, 2]},
        ],
    }


def write(tmp_path: Path, data: dict, name="cell.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def box_at_floor(cell: zn.Cell, x: float, y: float, camera="cam0", half_width=30,
                 height=200) -> list[float]:
    """A person box whose bottom-centre is the image of floor point (x, y)."""
    px, front = cell.camera_models[camera].project(np.array([[x, y, 0.0]]))
    assert front[0]
    u, v = px[0]
    return [u - half_width, v - height, u + half_width, v]


def open_box_stl(path: Path) -> None:
    mesh = trimesh.creation.box(extents=(1, 1, 1))
    mesh.update_faces(np.arange(len(mesh.faces)) != 0)  # drop one triangle: not closed
    mesh.export(path)


# ---------------------------------------------------------------------------- demo cell


def test_demo_cell_loads_clean():
    cell = zn.load_cell(DEMO)
    assert cell.warnings == ()
    kinds = sorted(z.kind for z in cell.zones)
    assert kinds == ["mask", "protective", "protective", "warning", "warning", "watch"]
    assert cell.spec.tool is not None and cell.spec.tool.offset.rpy_deg == (0.0, 0.0, 180.0)


def test_demo_cell_matches_the_demo_scene_camera():
    cell = zn.load_cell(DEMO)
    model = cell.camera_models["cam0"]
    np.testing.assert_allclose(model.rotation, DEMO_CAMERA.rotation, atol=1e-8)
    np.testing.assert_allclose(model.translation_m, DEMO_CAMERA.translation, atol=1e-8)
    np.testing.assert_allclose(model.camera_matrix, DEMO_CAMERA.K)


@pytest.mark.parametrize("image_id, volume_id", [("cam0-protective", "robot-protective"),
                                                 ("cam0-warning", "robot-warning")])
def test_demo_image_polygons_are_the_projected_floor_squares(image_id, volume_id):
    cell = zn.load_cell(DEMO)
    vol = cell.zone(volume_id)
    if vol.shape == "box":
        lo, hi = vol.min_m, vol.max_m
        floor = [[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]]
    else:
        floor = vol.points_m
    px = DEMO_CAMERA.project(np.c_[np.array(floor), np.zeros(4)])
    np.testing.assert_allclose(np.array(cell.zone(image_id).points_px), px, atol=0.1)


def test_demo_scene_positions_give_expected_hits():
    cell = zn.load_cell(DEMO)
    boxes = np.array([
        box_at_floor(cell, 0.2, 0.3),  # 0: at the robot -> protective + warning
        box_at_floor(cell, 1.9, -1.8),  # 1: warning area only
        box_at_floor(cell, 0.0, 4.5),  # 2: beyond everything
        [60, 100, 120, 250],  # 3: the poster -> masked
    ])
    rep = zn.check_persons(cell, "cam0", boxes)
    by_person = {}
    for h in rep.hits:
        by_person.setdefault(h.person, set()).add(h.zone_id)
    assert by_person[0] == {"robot-protective", "robot-warning", "cam0-protective",
                            "cam0-warning"}
    assert by_person[1] == {"robot-warning", "cam0-warning"}
    assert 2 not in by_person and 3 not in by_person
    assert rep.masked == ()  # mask zones apply before box merging (pipeline), not here
    assert rep.config_hash == cell.config_hash
    for h in rep.hits:
        assert h.speed_scale == (0.3 if h.kind == "warning" else 0.0)
        assert h.distance_m == (None if h.zone_id.startswith("cam0") else 0.0)


def test_no_persons_no_hits():
    cell = zn.load_cell(DEMO)
    rep = zn.check_persons(cell, "cam0", np.zeros((0, 4)))
    assert rep.hits == () and rep.masked == () and rep.tool_separation_m is None


def test_unknown_camera_in_query_is_a_config_error():
    with pytest.raises(ConfigError, match="unknown camera 'cam9'"):
        zn.check_persons(zn.load_cell(DEMO), "cam9", np.zeros((0, 4)))


# ---------------------------------------------------------------------------- validation faults


def _set(path: list, value):
    def mutate(d):
        target = d
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
    return mutate


def _append_zone(zone: dict):
    return lambda d: d["zones"].append(zone)


FAULTS = [
    pytest.param(_set(["zones", 0, "points_px"], [[100, 100], [400, 400], [400, 100],
                                                   [100, 400]]),
                 "zone 'img-stop'", "self-intersecting", id="self-intersecting"),
    pytest.param(_set(["zones", 0, "points_px"], [[100, 100], [200, 200], [300, 300]]),
                 "zone 'img-stop'", "degenerate polygon", id="degenerate"),
    pytest.param(_set(["zones", 0, "points_px"], [[100, 100], [200, 200]]),
                 "zone 'img-stop'", "at least 3 points", id="two-points"),
    pytest.param(_set(["zones", 0, "points_px"], [[100, 100], [1300, 100], [400, 400]]),
                 "zone 'img-stop'", "outside the 1280x720 image", id="outside-image"),
    pytest.param(_set(["zones", 1, "z_min_m"], 2.0), "zone 'vol-slow'", "z_min >= z_max",
                 id="z-min-ge-z-max"),
    pytest.param(_set(["zones", 2, "max_m"], [1, 1, -1]), "zone 'vol-stop'", "z_min >= z_max",
                 id="box-z"),
    pytest.param(_set(["zones", 0, "kind"], "danger"), "zone 'img-stop'", "unknown kind 'danger'",
                 id="unknown-kind"),
    pytest.param(_set(["zones", 2, "id"], "vol-slow"), "zone 'vol-slow'", "duplicate zone id",
                 id="duplicate-id"),
    pytest.param(_append_zone({"id": "m", "kind": "protective", "shape": "mesh",
                               "file": "missing.stl"}), "zone 'm'", "not found",
                 id="mesh-missing"),
    pytest.param(_append_zone({"id": "m", "kind": "protective", "shape": "mesh",
                               "file": "open.stl"}), "zone 'm'", "not closed", id="mesh-open"),
    pytest.param(_set(["zones", 0, "camera"], "cam7"), "zone 'img-stop'", "unknown camera 'cam7'",
                 id="unknown-camera"),
    pytest.param(_set(["cameras", 0, "calibration"],
                      {"type": "homography", "pairs": [[0, 0, 0, 0], [100, 0, 1, 0],
                                                       [0, 100, 0, 1]]}),
                 "camera 'cam0'", "at least 4 point pairs", id="three-pairs"),
    pytest.param(_set(["cameras", 0, "calibration"],
                      {"type": "homography", "pairs": [[0, 0, 0, 0], [100, 0, 1, 0],
                                                       [200, 0, 2, 0], [0, 100, 0, 1]]}),
                 "camera 'cam0'", "degenerate", id="degenerate-homography"),
    pytest.param(_set(["zones", 1, "height"], 3), "zone 'vol-slow'", "unknown field 'height'",
                 id="unknown-field"),
    pytest.param(lambda d: d["zones"][1].pop("speed_scale"), "zone 'vol-slow'",
                 "needs speed_scale", id="warning-without-scale"),
    pytest.param(_set(["zones", 1, "speed_scale"], 1.5), "zone 'vol-slow'", "speed_scale",
                 id="scale-out-of-bounds"),
    pytest.param(_set(["zones", 0, "shape"], "blob"), "zone 'img-stop'", "unknown shape 'blob'",
                 id="unknown-shape"),
    pytest.param(_set(["cameras", 0, "calibration", "rotation"], [[1, 0, 0], [0, 1, 0],
                                                                  [0, 1, 1]]),
                 "camera 'cam0'", "not a rotation", id="bad-rotation"),
    pytest.param(_set(["zones", 0, "anchor"], "share"), "zone 'img-stop'", "needs min_share",
                 id="share-without-min"),
    pytest.param(_set(["person", ], {"radius_m": -1}), "person", "radius_m", id="person-bounds"),
]


@pytest.mark.parametrize("mutate, where, fragment", FAULTS)
def test_every_fault_is_named_and_leaves_the_file_unchanged(tmp_path, mutate, where, fragment):
    open_box_stl(tmp_path / "open.stl")
    path = write(tmp_path, base_data())
    before = path.read_bytes()
    zn.load_cell(path)  # the starting file is valid
    data = base_data()
    mutate(data)
    with pytest.raises(ConfigError) as err:
        zn.write_cell_data(data, path)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}: ")
    assert where in msg and fragment in msg, msg
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.yaml", "open.stl"]
    # the same fault in a file on disk is refused on load with the same message
    bad = write(tmp_path, data, "bad.yaml")
    with pytest.raises(ConfigError, match=fragment):
        zn.load_cell(bad)


def test_volume_zone_without_any_calibration_is_refused(tmp_path):
    data = base_data()
    del data["cameras"][0]["calibration"]
    with pytest.raises(ConfigError, match="zone 'vol-slow': volume zone but no camera has a "
                                          "calibration"):
        zn.parse_cell(data, tmp_path / "x.yaml")


def test_yaml_syntax_error_names_the_line(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("version: 1\ncameras:\n  - id: cam0\n    width: [1280\n")
    with pytest.raises(ConfigError, match=r"broken\.yaml:\d+:\d+: YAML syntax error"):
        zn.load_cell(path)


def test_duplicate_yaml_key_is_refused(tmp_path):
    text = yaml.safe_dump(base_data(), sort_keys=False).replace(
        "  kind: protective\n", "  kind: protective\n  kind: mask\n", 1)
    path = tmp_path / "dup.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"dup\.yaml:\d+:\d+: YAML syntax error: duplicate key "
                                          "'kind'"):
        zn.load_cell(path)


def test_non_finite_numbers_are_refused():
    data = base_data()
    data["zones"][2]["max_m"] = [1, float("nan"), 2]
    with pytest.raises(ConfigError, match=r"zone 'vol-stop': max_m\.1: Input should be a finite"):
        zn.parse_cell(data)


def test_validate_lists_every_fault(tmp_path):
    data = base_data()
    data["zones"][0]["camera"] = "nope"
    data["zones"][1]["z_min_m"] = 5
    errors, _ = zn.cell_faults(data, tmp_path / "c.yaml")
    assert len(errors) == 2
    with pytest.raises(ConfigError, match=r"\(and 1 more"):
        zn.parse_cell(data, tmp_path / "c.yaml")


def test_closed_mesh_zone_is_accepted_and_contains_persons(tmp_path):
    trimesh.creation.box(extents=(4, 4, 3), transform=trimesh.transformations.translation_matrix(
        [0, 0, 1.5])).export(tmp_path / "room.stl")
    data = base_data()
    data["zones"] = [{"id": "room", "kind": "protective", "shape": "mesh", "file": "room.stl"}]
    cell = zn.parse_cell(data, write(tmp_path, data))
    boxes = np.array([box_at_floor(cell, 0.3, 0.2), box_at_floor(cell, 3.5, 0.0)])
    rep = zn.check_persons(cell, "cam0", boxes)
    # person 0 stands well inside: no surface contact, found by the containment test
    assert [(h.zone_id, h.person) for h in rep.hits] == [("room", 0)]


# ---------------------------------------------------------------------------- config hash


def test_config_hash_is_stable_and_order_independent(tmp_path):
    data = base_data()
    h0 = zn.parse_cell(data).config_hash
    assert zn.parse_cell(copy.deepcopy(data)).config_hash == h0
    shuffled = copy.deepcopy(data)
    random.Random(1).shuffle(shuffled["zones"])
    shuffled["zones"] = [dict(reversed(list(z.items()))) for z in shuffled["zones"]]
    shuffled = dict(reversed(list(shuffled.items())))
    assert zn.parse_cell(shuffled).config_hash == h0
    # display names and disabled zones do not change the active set
    renamed = copy.deepcopy(data)
    renamed["zones"][0]["name"] = "Another name"
    renamed["zones"].append({"id": "off", "kind": "mask", "enabled": False, "shape": "polygon",
                             "camera": "cam0", "points_px": [[0, 0], [10, 0], [10, 10]]})
    assert zn.parse_cell(renamed).config_hash == h0
    # and it survives a save / load round trip
    path = tmp_path / "c.yaml"
    zn.save_cell(zn.parse_cell(data, path), path)
    assert zn.load_cell(path).config_hash == h0


@pytest.mark.parametrize("mutate", [
    pytest.param(_set(["zones", 0, "points_px", 0], [101, 100]), id="moved-point"),
    pytest.param(_set(["zones", 1, "speed_scale"], 0.5), id="speed-scale"),
    pytest.param(_set(["zones", 2, "enabled"], False), id="disabled"),
    pytest.param(_set(["person", ], {"radius_m": 0.35}), id="person"),
    pytest.param(_set(["cameras", 0, "calibration", "translation_m", 2], 6.8), id="calibration"),
])
def test_config_hash_changes_with_the_active_set(mutate):
    data = base_data()
    h0 = zn.parse_cell(data).config_hash
    mutate(data)
    assert zn.parse_cell(data).config_hash != h0


# ---------------------------------------------------------------------------- saving


def test_save_is_atomic_and_keeps_a_backup(tmp_path):
    path = write(tmp_path, base_data())
    original = path.read_bytes()
    data = base_data()
    data["zones"].pop(0)
    cell = zn.write_cell_data(data, path)
    assert (tmp_path / "cell.yaml.bak").read_bytes() == original
    again = zn.load_cell(path)
    assert again.config_hash == cell.config_hash
    assert [z.id for z in again.zones] == ["vol-slow", "vol-stop"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.yaml", "cell.yaml.bak"]


# ---------------------------------------------------------------------------- anchors


def _image_cell(anchor: str, min_share: float | None = None, kind="protective") -> zn.Cell:
    zone = {"id": "z", "kind": kind, "shape": "polygon", "camera": "cam0", "anchor": anchor,
            "points_px": [[200, 200], [600, 150], [700, 500], [300, 600]]}
    if min_share is not None:
        zone["min_share"] = min_share
    if kind == "warning":
        zone["speed_scale"] = 0.5
    return zn.parse_cell({"version": 1, "cameras": [{"id": "cam0", "width": 1280,
                                                     "height": 720}], "zones": [zone]})


def _random_boxes(rng, n=400) -> np.ndarray:
    x1 = rng.uniform(0, 1100, n)
    y1 = rng.uniform(0, 600, n)
    return np.c_[x1, y1, x1 + rng.uniform(20, 180, n), y1 + rng.uniform(20, 300, n)]


@pytest.mark.parametrize("anchor", ["bottom-centre", "centre"])
def test_point_anchors_agree_with_shapely(anchor):
    cell = _image_cell(anchor)
    poly = shapely.Polygon(cell.zone("z").points_px)
    boxes = _random_boxes(np.random.default_rng(7))
    rep = zn.check_persons(cell, "cam0", boxes)
    hit = {h.person for h in rep.hits}
    cx = (boxes[:, 0] + boxes[:, 2]) / 2
    cy = boxes[:, 3] if anchor == "bottom-centre" else (boxes[:, 1] + boxes[:, 3]) / 2
    ref = shapely.contains_xy(poly, cx, cy)
    assert hit == set(np.flatnonzero(ref).tolist())
    assert 20 < len(hit) < 380


def test_share_anchor_agrees_with_shapely_areas():
    cell = _image_cell("share", 0.5)
    poly = shapely.Polygon(cell.zone("z").points_px)
    rng = np.random.default_rng(8)
    boxes = np.round(_random_boxes(rng))
    hit = {h.person for h in zn.check_persons(cell, "cam0", boxes).hits}
    shares = np.array([poly.intersection(shapely.box(*b)).area / shapely.box(*b).area
                       for b in boxes])
    clear = np.abs(shares - 0.5) > 0.03  # pixel counting vs exact area near the threshold
    ref = set(np.flatnonzero((shares >= 0.5) & clear).tolist())
    assert {i for i in hit if clear[i]} == ref
    assert len(ref) > 20


def test_any_overlap_anchor_agrees_with_shapely():
    cell = _image_cell("any-overlap", kind="warning")
    poly = shapely.Polygon(cell.zone("z").points_px)
    boxes = np.round(_random_boxes(np.random.default_rng(9)))
    rep = zn.check_persons(cell, "cam0", boxes)
    hit = {h.person for h in rep.hits}
    areas = np.array([poly.intersection(shapely.box(*b)).area for b in boxes])
    clear = (areas == 0) | (areas > 4)  # touching by less than a few pixels may go either way
    assert {i for i in hit if clear[i]} == set(np.flatnonzero(areas > 4).tolist())
    assert all(h.speed_scale == 0.5 and h.kind == "warning" for h in rep.hits)


# ---------------------------------------------------------------------------- volumes, masks, tool


def test_unplaceable_person_hits_every_volume_zone():
    data = base_data()
    data["cameras"][0]["calibration"] = pinhole(eye=(0, -6, 1.5), target=(0, 0, 1.5))
    # the image zones were drawn for a camera looking down: beyond this level one's horizon
    data["zones"] = [z for z in data["zones"] if z.get("shape") != "polygon"]
    cell = zn.parse_cell(data)
    boxes = np.array([[600, 100, 680, 300]])  # bottom at row 300: above the horizon (row 360)
    rep = zn.check_persons(cell, "cam0", boxes)
    vol = {(h.zone_id, h.distance_m) for h in rep.hits if h.zone_id.startswith("vol")}
    assert vol == {("vol-slow", None), ("vol-stop", None)}


def test_mask_volume_does_not_hide_a_person_in_the_zone_check():
    # masking happens before box merging (the pipeline's rule): a box reaching the zone check
    # is a person, even when it stands in a mask volume
    data = base_data()
    data["zones"].append({"id": "mannequin", "kind": "mask", "shape": "cylinder",
                          "center_m": [0.5, 0.5], "radius_m": 0.4, "z_min_m": 0,
                          "z_max_m": 2})
    cell = zn.parse_cell(data)
    boxes = np.array([box_at_floor(cell, 0.5, 0.6), box_at_floor(cell, -0.5, -0.5)])
    rep = zn.check_persons(cell, "cam0", boxes)
    assert rep.masked == ()
    assert {h.person for h in rep.hits} == {0, 1}
    assert "mannequin" not in {h.zone_id for h in rep.hits}


def test_person_near_a_box_edge_is_widened_by_z_d():
    data = base_data()
    data["zones"] = [data["zones"][2]]  # box x, y in [-1, 1]
    data["person"] = {"radius_m": 0.3, "height_m": 1.9, "position_uncertainty_m": 0.1}
    cell = zn.parse_cell(data)
    inside = box_at_floor(cell, 1.35, 0.0)  # 0.35 from the face: within 0.3 + 0.1
    outside = box_at_floor(cell, 1.45, 0.0)  # 0.45 from the face
    rep = zn.check_persons(cell, "cam0", np.array([inside, outside]))
    assert [h.person for h in rep.hits] == [0]


def test_tool_separation_matches_closed_form():
    cell = zn.load_cell(DEMO)
    # tool at (2, 0, 1) not turned; the demo offset is the tracker's mounting on the tool
    # (tracker_in_tool), so the tool origin is pose @ inverse(offset): -Rz(180)^T t =
    # (13.55, 1.82, -49.17) mm, and the cylinder (r 0.05, 0.3 m) runs vertically from there
    pose = geo.ToolPose((2.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0), time=0.0)
    origin = zn.tool_object(cell.prepared, pose).getTranslation() - [0, 0, 0.15]
    np.testing.assert_allclose(origin, [2.01355, 0.00182, 1.0 - 0.04917], atol=1e-9)
    # a person in front of the robot base (one standing where the base is drawn may have
    # hidden feet: placed from the head, tests/test_coverage.py)
    boxes = np.array([box_at_floor(cell, 0.0, -1.5), box_at_floor(cell, -1.5, 1.0)])
    rep = zn.check_persons(cell, "cam0", boxes, tool_pose=pose, tool_speed_mps=0.5)
    expected = math.hypot(2.01355, 1.50182) - 0.3 - 0.05  # nominal person radius, no Z_d
    assert rep.tool_separation_m == pytest.approx(expected, abs=1e-3)
    sep = cell.prepared.separation  # the demo file sets T_r and C itself
    assert rep.required_separation_m == pytest.approx(
        geo.protective_separation_m(0.5, sep, 0.1))
    # unknown speed: the configured default speed
    rep2 = zn.check_persons(cell, "cam0", boxes, tool_pose=pose)
    assert rep2.required_separation_m == pytest.approx(geo.protective_separation_m(1.0, sep, 0.1))


def test_volume_distances_match_closed_form():
    cell = zn.parse_cell(base_data())  # vol-slow: square 2 m half-width; vol-stop: 1 m
    pts = [(0.0, 0.0), (1.8, 0.0), (3.0, 0.5), (2.5, 2.6)]
    ids, dist = zn.volume_distances(cell, "cam0", np.array([box_at_floor(cell, *p)
                                                            for p in pts]))
    assert ids == ("vol-slow", "vol-stop")
    r = 0.4  # radius + Z_d
    for i, p in enumerate(pts):
        for k, half in enumerate((2.0, 1.0)):
            expected = max(_rect_distance(p, half) - r, 0.0)
            assert dist[i, k] == pytest.approx(expected, abs=1e-3), (p, ids[k])


def test_tool_offset_direction_is_explicit():
    data = base_data()
    pose = geo.ToolPose((0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0), time=0.0)
    origins = {}
    for given_as in ("tool_in_tracker", "tracker_in_tool"):
        data["tool"] = {"shape": "sphere", "radius_m": 0.05,
                        "offset": {"translation_mm": [10, 0, 50], "rpy_deg": [0, 0, 180],
                                   "given_as": given_as}}
        prep = zn.parse_cell(data).prepared
        origins[given_as] = zn.tool_object(prep, pose).getTranslation()
    np.testing.assert_allclose(origins["tool_in_tracker"], [0.01, 0.0, 1.05], atol=1e-12)
    np.testing.assert_allclose(origins["tracker_in_tool"], [0.01, 0.0, 0.95], atol=1e-12)


def test_tool_touching_a_person_gives_zero():
    cell = zn.load_cell(DEMO)
    pose = geo.ToolPose((0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0), time=0.0)
    rep = zn.check_persons(cell, "cam0", np.array([box_at_floor(cell, 0.1, 0.0)]), pose)
    assert rep.tool_separation_m == 0.0
    # no persons: nobody to measure
    rep = zn.check_persons(cell, "cam0", np.zeros((0, 4)), pose)
    assert rep.tool_separation_m is None


def test_prepared_cell_is_built_once_and_reused():
    cell = zn.load_cell(DEMO)
    assert cell.prepared is cell.prepared
    boxes = np.array([box_at_floor(cell, 0.2, 0.3)])
    assert zn.check_persons(cell.prepared, "cam0", boxes) == zn.check_persons(cell, "cam0", boxes)


# ------------------------------------------------------------------ watch regions, drawing


def test_watch_regions_image_and_projected_volume():
    data = base_data()
    data["zones"].append({"id": "shelf", "kind": "watch", "shape": "polygon", "camera": "cam0",
                          "points_px": [[1000, 120], [1200, 120], [1200, 300], [1000, 300]]})
    data["zones"].append({"id": "cabinet", "kind": "watch", "shape": "box",
                          "min_m": [2.0, 1.0, 0.0], "max_m": [2.5, 1.5, 1.0]})
    cell = zn.parse_cell(data)
    regions = dict(zn.watch_regions(cell, "cam0"))
    assert set(regions) == {"shelf", "cabinet"}
    np.testing.assert_array_equal(regions["shelf"], [[1000, 120], [1200, 120], [1200, 300],
                                                     [1000, 300]])
    corners = np.array([[x, y, z] for x in (2.0, 2.5) for y in (1.0, 1.5) for z in (0.0, 1.0)])
    px, _ = cell.camera_models["cam0"].project(corners)
    hull = shapely.MultiPoint(px).convex_hull
    assert shapely.Polygon(regions["cabinet"]).area == pytest.approx(hull.area, rel=1e-3)
    assert regions["cabinet"].dtype == np.float32


def test_watch_region_out_of_view_is_left_out():
    data = base_data()
    data["zones"].append({"id": "behind", "kind": "watch", "shape": "box",
                          "min_m": [-1, -9, 0], "max_m": [1, -8, 1]})  # behind the camera
    assert zn.watch_regions(zn.parse_cell(data), "cam0") == []


def test_draw_zones_changes_pixels_inside_only():
    cell = _image_cell("bottom-centre")
    frame = np.full((720, 1280, 3), 128, np.uint8)
    out = zn.draw_zones(frame, cell, "cam0", hit_zone_ids=("z",))
    assert out.shape == frame.shape and frame.mean() == 128  # the input is not touched
    assert np.any(out[400, 450] != frame[400, 450])  # inside the polygon
    assert np.all(out[700, 1200] == frame[700, 1200])  # far outside
    small = zn.draw_zones(frame[::2, ::2], cell, "cam0")  # a half-size frame is drawn scaled
    assert np.any(small[200, 225] != 128)


@pytest.mark.parametrize("seed", range(3))
def test_tool_separation_equals_brute_force_minimum(seed):
    import fcl

    cell = zn.load_cell(DEMO)
    prep = cell.prepared
    rng = np.random.default_rng(seed)
    for _ in range(20):
        floor = rng.uniform(-2.5, 2.5, size=(8, 2))
        # not on or behind the robot base: such boxes may hide the feet and are placed from
        # the head (a range, not the bottom pixel this brute force uses)
        floor = floor[(np.abs(floor[:, 0]) > 1.0) | (floor[:, 1] < -0.7)]
        boxes = np.array([box_at_floor(cell, x, y) for x, y in floor]).reshape(-1, 4)
        q = rng.normal(size=4)
        pose = geo.ToolPose(tuple(rng.uniform([-2, -2, 0.2], [2, 2, 2.0])), tuple(q / 3), 0.0)
        rep = zn.check_persons(prep, "cam0", boxes, tool_pose=pose)
        tool = zn.tool_object(prep, pose)
        placed, _ = cell.camera_models["cam0"].pixel_to_floor(
            np.c_[(boxes[:, 0] + boxes[:, 2]) / 2, boxes[:, 3]])
        brute = min(max(fcl.distance(geo.fcl_vertical_cylinder(p, 0.3, 0.0, 1.9), tool), 0.0)
                    for p in placed)
        # less FCL's measured over-report (a safety margin, monitor.zones.separation)
        margin = zn_separation.FCL_DISTANCE_MARGIN_M
        assert rep.tool_separation_m == pytest.approx(max(brute - margin, 0.0), abs=1e-6)


def test_homography_calibration_undistorts_first():
    dist = np.array([-0.15, 0.04, 0.0005, -0.0003, 0.0])
    r, t = geo.look_at((0, -6.0, 3.2), (0, 0, 0.8))
    truth = geo.CameraModel.pinhole(1280, 720, np.array(K), dist, r, t)
    rng = np.random.default_rng(11)
    floor = rng.uniform(-2.5, 2.5, size=(10, 2))
    px, _ = truth.project(np.c_[floor, np.zeros(10)])
    data = base_data()
    data["zones"] = data["zones"][1:]
    data["cameras"][0]["calibration"] = {
        "type": "homography", "pairs": np.c_[px, floor].tolist(), "camera_matrix": K,
        "distortion": dist.tolist()}
    cell = zn.parse_cell(data)
    test = rng.uniform(-2.5, 2.5, size=(50, 2))
    tpx, _ = truth.project(np.c_[test, np.zeros(50)])
    got, valid = cell.camera_models["cam0"].pixel_to_floor(tpx)
    assert valid.all() and np.abs(got - test).max() < 1e-4
    # without the distortion model the same pairs fit worse: the undistortion matters
    data["cameras"][0]["calibration"].pop("distortion")
    plain = zn.parse_cell(data).camera_models["cam0"]
    assert np.abs(plain.pixel_to_floor(tpx)[0] - test).max() > 1e-2


def test_demo_walk_enters_warning_then_protective_and_leaves():
    """The demo scene's walking path against the demo zones: the hits follow the floor
    position (volumes with the widened cylinder, image polygons by the feet)."""
    from monitor.scene import PERSON_HEIGHT_M, DemoScene

    cell = zn.load_cell(DEMO)
    scene = DemoScene()
    r = cell.spec.person.radius_m + cell.spec.person.position_uncertainty_m
    phases = []
    for t in np.arange(0.0, scene.duration_s, 0.1):
        x, y = scene.position_at(float(t))
        feet, head = DEMO_CAMERA.project(np.array([[x, y, 0.0], [x, y, PERSON_HEIGHT_M]]))
        if not 0 <= feet[0] <= 1280 or feet[1] > 720:
            continue
        w = 0.2 * (feet[1] - head[1])
        rep = zn.check_persons(cell, "cam0", np.array([[feet[0] - w, head[1], feet[0] + w,
                                                        feet[1]]]))
        got = {h.zone_id for h in rep.hits}
        for half, vol, img in ((1.0, "robot-protective", "cam0-protective"),
                               (2.5, "robot-warning", "cam0-warning")):
            d = _rect_distance((x, y), half)
            if abs(d - r) > 0.02:
                assert (vol in got) == (d < r), (t, x, y)
            outside = max(abs(x), abs(y)) - half
            if abs(outside) > 0.02:
                assert (img in got) == (outside < 0), (t, x, y)
        phase = ("stop" if "robot-protective" in got else "slow" if "robot-warning" in got
                 else "clear")
        if not phases or phases[-1] != phase:
            phases.append(phase)
    assert phases == ["clear", "slow", "stop", "slow", "clear"]


def _rect_distance(p, half):
    dx = max(abs(p[0]) - half, 0.0)
    dy = max(abs(p[1]) - half, 0.0)
    return math.hypot(dx, dy)


def test_mesh_zone_is_drawn_and_watched(tmp_path):
    trimesh.creation.box(extents=(1, 1, 1), transform=trimesh.transformations.translation_matrix(
        [0, 0, 0.5])).export(tmp_path / "crate.stl")
    data = base_data()
    data["zones"] = [{"id": "crate", "kind": "watch", "shape": "mesh", "file": "crate.stl"},
                     {"id": "crate-stop", "kind": "protective", "shape": "mesh",
                      "file": "crate.stl"}]
    cell = zn.parse_cell(data, write(tmp_path, data))
    (zid, region), = zn.watch_regions(cell, "cam0")
    px, _ = cell.camera_models["cam0"].project(np.array([[0.0, 0.0, 0.5]]))
    assert zid == "crate" and geo.points_in_polygon(px, region)[0]
    frame = np.zeros((720, 1280, 3), np.uint8)
    out = zn.draw_zones(frame, cell, "cam0")
    assert np.any(out[int(px[0, 1]) - 40:int(px[0, 1]) + 40, int(px[0, 0]) - 60:int(px[0, 0]) + 60])


def test_merge_towards_danger_keeps_every_hit_and_the_worse_values():
    from monitor.types import ZoneHit, ZoneReport
    from monitor.zones import merge_towards_danger

    a = ZoneReport(hits=(ZoneHit("W", "warning", 0, 0.3, 0.4),), masked=(1, 2),
                   tool_separation_m=1.2, required_separation_m=0.8, config_hash="h")
    b = ZoneReport(hits=(ZoneHit("W", "warning", 0, 0.3, 0.0), ZoneHit("P", "protective", 0, 0.0)),
                   masked=(2,), tool_separation_m=0.9, required_separation_m=0.8, config_hash="h")
    m = merge_towards_danger(a, b)
    assert {(h.zone_id, h.distance_m) for h in m.hits} == {("W", 0.0), ("P", None)}
    assert m.masked == (2,)
    assert m.tool_separation_m == 0.9 and m.required_separation_m == 0.8


def test_foot_uncertainty_finds_a_person_whose_box_reaches_too_low():
    from monitor.scene import DEMO_CAMERA

    cell = zn.load_cell(DEMO)
    # a person just in front of the protective floor square, seen from the camera
    feet = np.array([[0.0, -1.45, 0.0]])
    u, v = DEMO_CAMERA.project(feet)[0]
    box = np.array([[u - 40, v - 250, u + 40, v]])
    plain = zn.check_persons(cell, "cam0", box)
    assert not any(h.kind == "protective" for h in plain.hits)
    wary = zn.check_persons(cell, "cam0", box, foot_uncertainty_px=60.0)
    assert any(h.kind == "protective" for h in wary.hits)
