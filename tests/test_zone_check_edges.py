"""The per-frame zone check at its edges: a person who cannot be placed on the floor, the foot
band's two ends, a camera without calibration, the unknown-camera message (cases from mutation
testing of monitor/zones/check.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from monitor import geometry as geo
from monitor.config import demo_cell_path
from monitor.errors import ConfigError
from monitor.types import ZoneHit
from monitor.zones import check_persons, load_cell, parse_cell


def demo_data() -> dict:
    return yaml.safe_load(demo_cell_path().read_text())


def test_a_person_who_cannot_be_placed_is_in_every_protective_and_warning_volume(tmp_path):
    """A level camera: a box wholly above the horizon has no floor point (feet nor head), so
    the person counts inside every protective and warning volume (fail safe)."""
    data = demo_data()
    r, t = geo.look_at((0.0, -6.0, 1.5), (0.0, 0.0, 1.5))
    data["cameras"][0]["calibration"].update(rotation=r.tolist(), translation_m=t.tolist())
    data["zones"] = [z for z in data["zones"] if "points_px" not in z]  # volumes only
    path = Path(tmp_path) / "level.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    cell = load_cell(path)
    box = np.array([[600.0, 150.0, 680.0, 300.0]])  # the horizon is row 360
    report = check_persons(cell, "cam0", box, foot_band_px=(0.0, 0.0))
    volumes = {z["id"]: z for z in data["zones"] if z["kind"] in ("protective", "warning")}
    assert set(report.hits) == {
        ZoneHit(zid, z["kind"], 0, z.get("speed_scale", 0.0) if z["kind"] == "warning"
                else 0.0, None) for zid, z in volumes.items()}


def test_both_ends_of_the_foot_band_count():
    """A box whose bottom edge lies just inside the top edge of the demo's image protective
    zone (rows 403.5..532): only the bottom end of the band (the box's own bottom) is inside."""
    cell = load_cell(demo_cell_path())
    box = np.array([[600.0, 250.0, 680.0, 410.0]])
    hits = {h.zone_id for h in check_persons(cell, "cam0", box, foot_band_px=(0.0, 49.0)).hits}
    assert "cam0-protective" in hits


def uncalibrated_cell() -> object:
    return parse_cell({
        "version": 1,
        "cameras": [{"id": "cam9", "width": 640, "height": 480}],
        "zones": [{"id": "strip", "kind": "protective", "shape": "polygon", "camera": "cam9",
                   "points_px": [[100, 300], [540, 300], [540, 340], [100, 340]]}],
    })


@pytest.mark.parametrize(("box", "band", "inside"), [
    pytest.param([300, 200, 340, 360], (0.0, 0.0), False, id="bottom-20px-below-no-band"),
    pytest.param([300, 200, 340, 360], (0.0, 49.0), True, id="bottom-20px-below-band-49"),
    pytest.param([300, 352, 340, 362], (0.0, 49.0), False, id="short-box-top-below-zone"),
    pytest.param([300, 200, 340, 298], (5.0, 49.0), False, id="zone-just-below-band-lo-5"),
    pytest.param([300, 200, 340, 306], (5.0, 49.0), True, id="band-lo-5-reaches-in"),
])
def test_image_zones_of_a_camera_without_calibration_use_the_band_in_pixels(box, band, inside):
    report = check_persons(uncalibrated_cell(), "cam9", np.array([box], float),
                           foot_band_px=band)
    assert (report.hits == (ZoneHit("strip", "protective", 0, 0.0, None),)) is inside
    assert inside or report.hits == ()


def test_an_unknown_camera_names_the_cameras_there_are(tmp_path):
    data = demo_data()
    data["cameras"].append(dict(data["cameras"][0], id="cam1"))
    path = Path(tmp_path) / "two.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError, match=r"unknown camera 'cam7' \(cameras: cam0, cam1\)"):
        check_persons(load_cell(path), "cam7", np.zeros((0, 4)))


@pytest.mark.parametrize("gap_m", [0.8, 1.37, 2.05])
def test_a_hidden_feet_persons_tool_separation_never_exceeds_the_true_distance(gap_m):
    """A person whose feet may be hidden is a range of floor positions, which the check samples
    every 0.1 m and then takes half a step off: the separation it reports is a lower bound of
    the true distance (never more), and no more than half a step below it. The tool stands on
    the range's line beyond its near end, so the true distance is known exactly."""
    from monitor.geometry import occlusion as occ

    cell = load_cell(demo_cell_path())
    prep, cam = cell.prepared, cell.cameras["cam0"]
    model = cell.camera_models["cam0"]
    # only the upper 60 cm of a standing person at (0.5, -2.5) show: the feet may be hidden
    foot, cut, head = model.project(np.array([[0.5, -2.5, 0.0], [0.5, -2.5, 1.15],
                                              [0.5, -2.5, 1.75]]))[0]
    box = np.array([[foot[0] - 40.0, head[1], foot[0] + 40.0, cut[1]]])
    place = occ.place_persons(box, model, cam.width, cam.height, band_px=(0.0, 0.0),
                              height_range_m=prep.height_range_m,
                              occluder_columns=prep.occluder_columns.get("cam0"),
                              camera_centre=prep.camera_centres.get("cam0"))
    assert place.located[0] and place.hidden[0]
    near, far = place.near_m[0], place.far_m[0]
    length = float(np.hypot(*(near - far)))
    assert length > 0.3  # a real range, several samples long
    # the demo tool is a vertical cylinder of radius 0.05 beside the person's (0.3): along the
    # line the distance between the two surfaces is gap_m. The pose is the tracker's, a few mm
    # off the tool's axis (the calibrated offset): place the axis itself.
    outward = (near - far) / length
    axis_xy = near + outward * (gap_m + prep.person.radius_m + 0.05)
    unit = geo.ToolPose((0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0), 0.0)
    shift = geo.tool_transform(unit, prep.tool.offset)[:2, 3]
    pose = geo.ToolPose((float(axis_xy[0] - shift[0]), float(axis_xy[1] - shift[1]), 1.0),
                        (0.0, 0.0, 0.0, 1.0), 0.0)
    report = check_persons(cell, "cam0", box, tool_pose=pose, tool_speed_mps=0.1,
                           foot_band_px=(0.0, 0.0))
    # (FCL measures a cylinder to within a millimetre)
    assert gap_m - 0.05 - 1e-3 <= report.tool_separation_m <= gap_m + 1e-6
