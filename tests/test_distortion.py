"""Lens distortion models that fold over the image are refused (monitor/geometry/distortion.py):
at load, by ``monitor zones validate``, ``monitor zones calibrate`` and ``monitor run``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from monitor import cli
from monitor import geometry as geo
from monitor import zones as zn
from monitor.errors import ConfigError
from tests.helpers import assert_one_line_error, run_here

DEMO = Path(__file__).resolve().parents[1] / "zones" / "demo-cell.yaml"
K = np.array([[900.0, 0.0, 640.0], [0.0, 900.0, 360.0], [0.0, 0.0, 1.0]])
FOLDING = [-0.45, 0.2, 0.0, 0.0, -0.04]  # the lens: r_d peaks just past the corners
ORDINARY = [
    [-0.1, 0.01, 0.0, 0.0, 0.0],
    [-0.12, 0.03, 0.001, -0.0005, 0.0],
    [-0.3, 0.1, 0.0, 0.0, -0.02],  # strong barrel that folds only well outside the image
    [0.2, 0.05, 0.0, 0.0, 0.0],  # pincushion
    [-0.28, 0.07, 0.0, 0.0, 0.0, 0.05, 0.0, 0.0],  # rational model
]


def demo_with_distortion(tmp_path: Path, dist: list[float], name: str = "cell.yaml") -> Path:
    path = tmp_path / name
    text = DEMO.read_text()
    assert "distortion: []" in text
    path.write_text(text.replace("distortion: []", f"distortion: {dist}"))
    return path


def test_the_folding_lens_maps_two_floor_points_to_one_pixel():
    """Why it is refused: with this model floor points far apart project to the same pixel
    (the monitor would place a person at either)."""
    # two rays along the image diagonal on both sides of the fold give the same r_d
    radii = np.linspace(0, 3, 30001)
    rd = geo.distortion.radial_distorted(radii, np.array(FOLDING))
    peak = int(np.argmax(rd))
    target = 0.8 * rd[peak]
    near = radii[np.argmin(np.abs(rd[:peak] - target))]
    far = radii[peak + np.argmin(np.abs(rd[peak:] - target))]
    assert far - near > 0.3  # two clearly different rays ...
    assert abs(geo.distortion.radial_distorted(np.array([near, far]), np.array(FOLDING))[0]
               - target) < 1e-3  # ... one distorted radius
    # and the fault names it
    fault = geo.distortion_fault(K, np.array(FOLDING), 1280, 720)
    assert fault is not None and "folds back" in fault and "two floor points" in fault


@pytest.mark.parametrize("dist", ORDINARY, ids=str)
def test_ordinary_distortions_pass(dist):
    assert geo.distortion_fault(K, np.array(dist), 1280, 720) is None


@pytest.mark.parametrize("dist", [
    [-0.45, 0.2, 0.0, 0.0, -0.04],
    [-0.6, 0.0, 0.0, 0.0, 0.0],  # folds well inside the image
    [0.0, 0.0, 0.3, 0.0, 0.0],  # a tangential term that folds
    [-0.1, 0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.2, 0.0],  # thin prism that folds
    [0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0],  # rational: r / (1 + 2 r^2) peaks at r = 0.7
], ids=str)
def test_folding_distortions_are_refused(dist):
    fault = geo.distortion_fault(K, np.array(dist), 1280, 720)
    assert fault is not None and ("fold" in fault or "non-finite" in fault)


def test_the_image_size_decides():
    """The same lens is fine on a smaller sensor crop: only the radii the image needs count."""
    assert geo.distortion_fault(K, np.array(FOLDING), 1280, 720) is not None
    small = np.array([[900.0, 0.0, 320.0], [0.0, 900.0, 240.0], [0.0, 0.0, 1.0]])
    assert geo.distortion_fault(small, np.array(FOLDING), 640, 480) is None


def test_a_zone_file_with_a_folding_lens_is_refused_at_load(tmp_path):
    with pytest.raises(ConfigError) as exc:
        zn.load_cell(demo_with_distortion(tmp_path, FOLDING))
    msg = str(exc.value)
    assert "\n" not in msg
    assert "camera 'cam0': calibration: distortion" in msg and "folds back" in msg


@pytest.mark.parametrize("dist", [[-0.1, 0.01, 0.0, 0.0, 0.0], []], ids=str)
def test_ordinary_lenses_and_the_demo_cell_still_load(tmp_path, dist):
    cell = zn.load_cell(demo_with_distortion(tmp_path, dist))
    assert "cam0" in cell.camera_models
    assert zn.load_cell(DEMO).camera_models


def test_a_homography_calibration_with_a_folding_lens_is_refused(tmp_path):
    data = yaml.safe_load(DEMO.read_text())
    r, t = geo.look_at((0, -6.0, 3.2), (0, 0, 0.8))
    cam = geo.CameraModel.pinhole(1280, 720, K, None, r, t)
    floor = np.array([[-2, -2], [2, -2], [2, 2], [-2, 2], [0, 0], [1, -1.5]], dtype=float)
    px, _ = cam.project(np.c_[floor, np.zeros(len(floor))])
    data["cameras"][0]["calibration"] = {"type": "homography", "pairs": np.c_[px, floor].tolist(),
                                         "camera_matrix": K.tolist(), "distortion": FOLDING}
    data["zones"] = [z for z in data["zones"] if z.get("shape") != "polygon"]
    with pytest.raises(ConfigError, match="camera 'cam0': calibration: distortion"):
        zn.parse_cell(data)
    data["cameras"][0]["calibration"]["distortion"] = ORDINARY[0]
    assert zn.parse_cell(data).camera_models["cam0"] is not None


def test_zones_validate_names_the_camera(tmp_path, capsys):
    path = demo_with_distortion(tmp_path, FOLDING)
    assert cli.main(["zones", "validate", str(path)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if ": error: " in line]
    assert len(err) == 1 and "camera 'cam0'" in err[0] and "fold" in err[0]


def test_zones_calibrate_refuses_a_folding_lens(tmp_path, capsys):
    """The calibration's result is checked the same way: a file whose lens folds is neither
    read for calibrating nor written with a new calibration."""
    path = demo_with_distortion(tmp_path, FOLDING)
    before = path.read_text()
    r, t = geo.look_at((0, -6.0, 3.2), (0, 0, 0.8))
    cam = geo.CameraModel.pinhole(1280, 720, K, None, r, t)
    floor = np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0], [0, 0, 1], [1, -1, 0.5]])
    px, _ = cam.project(floor)
    pairs = " ".join(",".join(f"{v:.6f}" for v in row) for row in np.c_[px, floor])
    assert cli.main(["zones", "calibrate", str(path), "--camera", "cam0", "--pairs", pairs,
                     "--pnp"]) == 2
    assert "camera 'cam0'" in capsys.readouterr().err
    assert path.read_text() == before


def test_monitor_run_refuses_a_folding_lens(tmp_path, synthetic_model):
    cell = demo_with_distortion(tmp_path, FOLDING)
    config = tmp_path / "monitor.toml"
    config.write_text(f'[model]\npath = "{synthetic_model}"\n[zones]\nfile = "{cell}"\n')
    assert_one_line_error(run_here("run", "--config", config, "--duration", "1"),
                          "camera 'cam0'", "folds back")
