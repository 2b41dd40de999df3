"""The cameras of a zone file from the command line (``monitor zones camera``), the one
``--camera`` rule of every command (several cameras: required, the error lists them; one: the
default), and edits that keep the file's own indentation."""

from __future__ import annotations

import difflib
from pathlib import Path

import cv2
import numpy as np
import pytest

from monitor import cli
from monitor import zones as zn
from tests.helpers import one_error_line as one_line_error
from tests.helpers import zones_cli as zones

POLY = "100,100 300,100 300,300 100,300"




@pytest.fixture
def one_cam(tmp_path) -> Path:
    f = tmp_path / "cell.yaml"
    assert zones("new", f, "--camera", "cam0", "--size", "640x480") == 0
    return f


@pytest.fixture
def two_cams(one_cam) -> Path:
    assert zones("camera", "add", one_cam, "cam1", "--size", "640x480") == 0
    return one_cam


# --- zones camera ---------------------------------------------------------------------------


def test_camera_add_then_a_protective_polygon_for_each_camera(two_cams, capsys):
    assert zones("add", two_cams, "p0", POLY, "--kind", "protective", "--camera", "cam0") == 0
    assert zones("add", two_cams, "p1", POLY, "--kind", "protective", "--camera", "cam1") == 0
    assert zones("validate", two_cams) == 0
    cell = zn.load_cell(two_cams)
    assert list(cell.cameras) == ["cam0", "cam1"]
    assert {z.id: z.camera for z in cell.zones} == {"p0": "cam0", "p1": "cam1"}
    capsys.readouterr()
    assert zones("camera", "add", two_cams, "cam1", "--size", "10x10") == 2
    assert "camera 'cam1' exists already" in one_line_error(capsys)


def test_unknown_camera_lists_the_cameras_and_says_how_to_add_one(one_cam, capsys):
    assert zones("add", one_cam, "p", POLY, "--kind", "protective", "--camera", "cam1") == 2
    err = one_line_error(capsys)
    assert "unknown camera 'cam1' (cameras: cam0)" in err
    assert f"monitor zones camera add {one_cam} cam1 --size WxH" in err


def test_camera_remove_refuses_a_camera_with_zones_unless_told(two_cams, capsys):
    assert zones("add", two_cams, "p1", POLY, "--kind", "protective", "--camera", "cam1") == 0
    before = two_cams.read_text()
    assert zones("camera", "remove", two_cams, "cam1") == 2
    assert "has image zones p1" in one_line_error(capsys)
    assert two_cams.read_text() == before
    assert zones("camera", "remove", two_cams, "cam1", "--with-zones") == 0
    cell = zn.load_cell(two_cams)
    assert list(cell.cameras) == ["cam0"] and cell.zones == ()
    assert zones("camera", "remove", two_cams, "cam0") == 2
    assert "only camera" in one_line_error(capsys)


def test_camera_set_size_rescales_only_when_told_and_rename_moves_its_zones(two_cams, capsys):
    assert zones("add", two_cams, "p1", POLY, "--kind", "protective", "--camera", "cam1") == 0
    assert zones("camera", "set", two_cams, "cam1", "--size", "1280x960") == 2
    assert "--rescale" in one_line_error(capsys)  # zones drawn in 640x480 pixels stay put
    assert zones("camera", "set", two_cams, "cam1", "--size", "1280x960", "--rescale",
                 "--new-id", "side") == 0
    cell = zn.load_cell(two_cams)
    assert (cell.cameras["side"].width, cell.cameras["side"].height) == (1280, 960)
    assert cell.zone("p1").camera == "side"
    assert cell.zone("p1").points_px[0] == (200.0, 200.0)


def test_camera_set_calibration_from_a_file(one_cam, tmp_path, capsys):
    cal = tmp_path / "cal.yaml"
    cal.write_text("type: homography\npairs: [[0, 0, 0, 0], [640, 0, 4, 0], [640, 480, 4, 3], "
                   "[0, 480, 0, 3], [320, 240, 2, 1.5]]\n")
    assert zones("camera", "set", one_cam, "--calibration", cal) == 0  # the only camera
    assert zn.load_cell(one_cam).cameras["cam0"].calibration.type == "homography"
    assert zones("camera", "set", one_cam, "--no-calibration") == 0
    assert zn.load_cell(one_cam).cameras["cam0"].calibration is None


# --- the --camera rule, one test per command ------------------------------------------------


def test_zones_add_needs_camera_with_several_and_defaults_with_one(one_cam, capsys):
    assert zones("add", one_cam, "p0", POLY, "--kind", "protective") == 0
    assert zn.load_cell(one_cam).zone("p0").camera == "cam0"
    assert zones("camera", "add", one_cam, "cam1", "--size", "640x480") == 0
    capsys.readouterr()
    before = one_cam.read_text()
    assert zones("add", one_cam, "p1", POLY, "--kind", "protective") == 2
    assert "2 cameras: say which with --camera (one of: cam0, cam1)" in one_line_error(capsys)
    assert one_cam.read_text() == before


PAIRS = "0,0,0,0 640,0,4,0 640,480,4,3 0,480,0,3 320,240,2,1.5 100,50,0.6,0.3"


def test_zones_edit_to_a_polygon_needs_camera_with_several(two_cams, capsys):
    assert zones("calibrate", two_cams, "--camera", "cam0", "--pairs", PAIRS) == 0
    assert zones("add", two_cams, "b", "--box=0,0,0,1,1,2", "--kind", "protective") == 0
    capsys.readouterr()
    assert zones("edit", two_cams, "b", "--points", POLY) == 2
    assert "(one of: cam0, cam1)" in one_line_error(capsys)
    assert zones("edit", two_cams, "b", "--points", POLY, "--camera", "cam9") == 2
    assert "unknown camera 'cam9' (cameras: cam0, cam1)" in one_line_error(capsys)
    assert zones("edit", two_cams, "b", "--points", POLY, "--camera", "cam1") == 0
    assert zn.load_cell(two_cams).zone("b").camera == "cam1"


def test_zones_preview_needs_camera_with_several_and_defaults_with_one(one_cam, tmp_path,
                                                                        capsys):
    frame = tmp_path / "f.png"
    cv2.imwrite(str(frame), np.full((480, 640, 3), 90, np.uint8))
    assert zones("preview", one_cam, "--frame", frame, "--out", tmp_path / "p.png") == 0
    assert "camera cam0" in capsys.readouterr().out
    assert zones("camera", "add", one_cam, "cam1", "--size", "640x480") == 0
    capsys.readouterr()
    assert zones("preview", one_cam, "--frame", frame, "--out", tmp_path / "q.png") == 2
    assert "(one of: cam0, cam1)" in one_line_error(capsys)
    assert not (tmp_path / "q.png").exists()


def test_zones_calibrate_needs_camera_with_several_and_defaults_with_one(one_cam, capsys):
    assert zones("calibrate", one_cam, "--pairs", PAIRS) == 0
    assert zn.load_cell(one_cam).cameras["cam0"].calibration is not None
    assert zones("camera", "add", one_cam, "cam1", "--size", "640x480") == 0
    capsys.readouterr()
    assert zones("calibrate", one_cam, "--pairs", PAIRS) == 2
    assert "(one of: cam0, cam1)" in one_line_error(capsys)


def _clip(path: Path, size: tuple[int, int] = (640, 480), frames: int = 5) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, size)
    for k in range(frames):
        writer.write(np.full((size[1], size[0], 3), 60 + 10 * k, np.uint8))
    writer.release()
    return path


def _config(path: Path, cameras: list[str]) -> Path:
    path.write_text("".join(f'[[camera]]\nid = "{c}"\nsource = "{c}.mp4"\n'
                            f'reference = "refs/{c}.png"\n' for c in cameras))
    for c in cameras:
        _clip(path.parent / f"{c}.mp4")
    return path


def test_reference_capture_needs_camera_with_several_and_defaults_with_one(tmp_path, capsys):
    one = _config(tmp_path / "one.toml", ["cam0"])
    assert cli.main(["reference", "capture", "--config", str(one), "--frames", "3"]) == 0
    assert "reference of camera cam0" in capsys.readouterr().out
    assert cv2.imread(str(tmp_path / "refs" / "cam0.png")).shape == (480, 640, 3)
    two = _config(tmp_path / "two.toml", ["cam0", "cam1"])
    assert cli.main(["reference", "capture", "--config", str(two)]) == 2
    assert "two.toml: has 2 cameras: say which with --camera (one of: cam0, cam1)" in \
        one_line_error(capsys)
    assert cli.main(["reference", "capture", "--config", str(two), "--camera", "cam1",
                     "--frames", "2"]) == 0
    assert (tmp_path / "refs" / "cam1.png").is_file()
    # without a file, a directory --out needs a camera to name the image: no silent cam0
    assert cli.main(["reference", "capture", "--source", str(tmp_path / "cam0.mp4"), "--out",
                     str(tmp_path)]) == 2
    assert "--camera" in one_line_error(capsys)


def test_replay_needs_camera_with_several_and_defaults_with_one(two_cams, tmp_path, capsys,
                                                                synthetic_model):
    assert zones("add", two_cams, "p0", POLY, "--kind", "protective", "--camera", "cam0") == 0
    assert zones("add", two_cams, "p1", POLY, "--kind", "protective", "--camera", "cam1") == 0
    video = _clip(tmp_path / "clip.mp4")
    capsys.readouterr()
    args = ["replay", str(video), "--zones", str(two_cams), "--model", str(synthetic_model),
            "--no-video"]
    assert cli.main([*args, "--out", str(tmp_path / "a")]) == 2
    err = one_line_error(capsys)
    assert "(one of: cam0, cam1)" in err and "video" not in err.split("error:")[1]
    assert cli.main([*args, "--out", str(tmp_path / "b"), "--camera", "cam1"]) == 0
    assert zones("camera", "remove", two_cams, "cam1", "--with-zones") == 0
    assert cli.main([*args, "--out", str(tmp_path / "c")]) == 0  # the only camera


# --- indentation ----------------------------------------------------------------------------

FOUR = """\
# a cell indented by four
version: 1
name: four
person:
    radius_m: 0.3
    height_m: 1.9
cameras:
    - id: cam0
      width: 640
      height: 480
zones:
    - id: p0
      kind: protective
      shape: polygon
      camera: cam0
      points_px:
          - [10.0, 10.0]
          - [200.0, 10.0]
          - [200.0, 200.0]
"""


@pytest.mark.parametrize("edit", [
    pytest.param(["add", "{f}", "p1", POLY, "--kind", "warning", "--speed-scale", "0.5"],
                 id="zones-add"),
    pytest.param(["camera", "add", "{f}", "cam1", "--size", "320x240"], id="zones-camera-add"),
])
def test_an_edit_keeps_the_files_four_space_indentation(tmp_path, edit):
    f = tmp_path / "cell.yaml"
    f.write_text(FOUR)
    assert zones(*[a.format(f=f) for a in edit]) == 0
    text = f.read_text()
    diff = list(difflib.unified_diff(FOUR.splitlines(), text.splitlines(),
                                     lineterm="", n=0))[2:]
    removed = [ln for ln in diff if ln.startswith("-") and not ln.startswith("---")]
    assert removed == [], removed  # only lines added: nothing re-indented
    added = [ln[1:] for ln in diff if ln.startswith("+") and not ln.startswith("+++")]
    assert any(ln.startswith("    - id: ") for ln in added), added
    assert all(not ln.startswith("  -") for ln in added), added


def test_zones_new_writes_the_layout_later_edits_keep(one_cam):
    first = one_cam.read_text()
    assert "cameras:\n  - id: cam0\n" in first
    assert zones("camera", "add", one_cam, "cam1", "--size", "640x480") == 0
    assert one_cam.read_text().startswith(first[:first.index("zones:")])
