"""A camera's reference image in the zone file (issue 21): ``monitor zones camera set
--reference``, ``zones camera list``, ``reference capture --zones``, and the service taking the
zone file's reference over monitor.toml's (warning when both name different files)."""

from __future__ import annotations

import difflib
from pathlib import Path

import cv2
import numpy as np
import pytest

from monitor import cli
from monitor import zones as zn
from monitor.config import parse_config
from monitor.errors import ConfigError
from monitor.health.references import (
    CONFIG,
    ZONE_FILE,
    choose_reference,
    reference_warnings,
)
from monitor.scene import write_video
from tests.helpers import one_error_line as one_line_error
from tests.helpers import zones_cli as zones

FOUR = """\
# a cell indented by four
version: 1
name: four
cameras:
    - id: cam0
      width: 64
      height: 48
    - id: cam1
      width: 64
      height: 48
zones:
    - id: p0
      kind: protective
      shape: polygon
      camera: cam0
      points_px:
          - [1.0, 1.0]
          - [40.0, 1.0]
          - [40.0, 40.0]
"""




def image(path: Path, width: int = 64, height: int = 48, level: int = 90) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.full((height, width, 3), level, np.uint8)
    img[::5, ::3] = 200
    assert cv2.imwrite(str(path), img)
    return path


@pytest.fixture
def cell(tmp_path) -> Path:
    f = tmp_path / "cell" / "cell.yaml"
    f.parent.mkdir()
    f.write_text(FOUR)
    return f


def test_set_reference_stores_a_zone_file_relative_path_keeping_the_indentation(
        cell, tmp_path, monkeypatch, capsys):
    ref = image(tmp_path / "refs" / "cam0.png")
    monkeypatch.chdir(tmp_path)  # the path given is the user's, relative to where they are
    assert zones("camera", "set", cell, "cam0", "--reference", "refs/cam0.png") == 0
    assert "reference ../refs/cam0.png" in capsys.readouterr().out
    loaded = zn.load_cell(cell)
    assert loaded.cameras["cam0"].reference == "../refs/cam0.png"
    assert loaded.cameras["cam1"].reference is None
    assert (cell.parent / loaded.cameras["cam0"].reference).resolve() == ref.resolve()
    diff = [ln for ln in difflib.unified_diff(FOUR.splitlines(), cell.read_text().splitlines(),
                                              lineterm="", n=0)
            if ln[:1] in "+-" and not ln.startswith(("+++", "---"))]
    assert diff == ["+      reference: ../refs/cam0.png"]  # one line, at the camera's indent
    assert Path(f"{cell}.bak").read_text() == FOUR  # the atomic save kept the old file
    assert zones("camera", "list", cell) == 0
    rows = capsys.readouterr().out.splitlines()
    assert rows[0].split()[-1] == "REFERENCE"
    assert rows[1].split()[0] == "cam0" and rows[1].split()[-1] == "../refs/cam0.png"
    assert rows[2].split()[0] == "cam1" and rows[2].split()[-1] == "-"


@pytest.mark.parametrize("bad, needle", [
    ("missing.png", "missing.png: no such file"),
    ("wrong.png", "is 80x48, the camera is 64x48"),
    ("garbage.png", "not a readable image"),
])
def test_a_bad_reference_is_refused_in_one_line_and_the_file_is_untouched(
        cell, tmp_path, capsys, bad, needle):
    image(tmp_path / "wrong.png", width=80)
    (tmp_path / "garbage.png").write_bytes(b"not a png")
    before = cell.read_bytes()
    assert zones("camera", "set", cell, "cam0", "--reference", tmp_path / bad) == 2
    err = one_line_error(capsys)
    assert needle in err and "--reference" in err
    assert cell.read_bytes() == before
    assert not Path(f"{cell}.bak").exists()


def test_a_size_change_needs_a_new_reference_and_no_reference_removes_it(cell, tmp_path,
                                                                         capsys):
    image(tmp_path / "small.png")
    image(tmp_path / "big.png", 128, 96)
    assert zones("camera", "set", cell, "cam1", "--reference", tmp_path / "small.png") == 0
    before = cell.read_bytes()
    assert zones("camera", "set", cell, "cam1", "--size", "128x96") == 2
    assert "has a reference image of 64x48" in one_line_error(capsys)
    assert cell.read_bytes() == before
    # the old reference does not fit the new size: refused with the size in one step
    assert zones("camera", "set", cell, "cam1", "--size", "128x96", "--reference",
                 tmp_path / "small.png") == 2
    assert "the camera is 128x96" in one_line_error(capsys)
    assert cell.read_bytes() == before
    assert zones("camera", "set", cell, "cam1", "--size", "128x96", "--reference",
                 tmp_path / "big.png") == 0
    assert zn.load_cell(cell).cameras["cam1"].reference.endswith("big.png")
    assert zones("camera", "set", cell, "cam1", "--no-reference") == 0
    assert zn.load_cell(cell).cameras["cam1"].reference is None
    assert "reference" not in cell.read_text()


def test_a_file_without_references_keeps_its_hash_and_setting_one_changes_it(cell, tmp_path):
    old = zn.load_cell(cell).config_hash
    image(tmp_path / "cam0.png")
    assert zones("camera", "set", cell, "cam0", "--reference", tmp_path / "cam0.png") == 0
    assert zn.load_cell(cell).config_hash != old
    assert zones("camera", "set", cell, "cam0", "--no-reference") == 0
    assert zn.load_cell(cell).config_hash == old


def test_the_zone_file_reference_wins_and_a_different_config_reference_is_a_warning(
        cell, tmp_path):
    image(tmp_path / "zone.png")
    assert zones("camera", "set", cell, "cam0", "--reference", tmp_path / "zone.png") == 0
    loaded = zn.load_cell(cell)
    chosen = choose_reference("cam0", str(tmp_path / "config.png"), loaded)
    assert chosen.named_in == ZONE_FILE and chosen.path == (tmp_path / "zone.png")
    assert chosen.warning and "config.png differs and is ignored" in chosen.warning
    same = choose_reference("cam0", str(tmp_path / "zone.png"), loaded)
    assert same.named_in == ZONE_FILE and same.warning is None
    other = choose_reference("cam1", str(tmp_path / "config.png"), loaded)
    assert other.named_in == CONFIG and other.path == tmp_path / "config.png"
    assert choose_reference("cam1", None, loaded).path is None
    config = parse_config({"camera": [
        {"id": "cam0", "source": "v.mp4", "reference": "config.png"},
        {"id": "cam1", "source": "v.mp4", "reference": "config.png"}],
        "zones": {"file": str(cell)}}, "monitor.toml", tmp_path)
    assert [w.split(":")[0] for w in reference_warnings(config, loaded)] == ["camera cam0"]


@pytest.mark.slow
def test_the_service_pipeline_checks_with_the_zone_file_reference(cell, tmp_path):
    """``build_pipeline`` (what ``monitor run`` starts from) gives cam0's health checker the
    zone file's image, not monitor.toml's; a zone file image replaced by one of another size
    since is refused at start in one line."""
    from monitor.service.setup import build_pipeline

    zone_ref = image(tmp_path / "zone.png", level=30)
    image(tmp_path / "config.png", level=220)
    video = tmp_path / "cam.mp4"
    write_video(video, iter([(np.zeros((48, 64, 3), np.uint8), None)] * 3), 10.0)
    assert zones("camera", "set", cell, "cam0", "--reference", zone_ref) == 0
    config = parse_config({
        "camera": [{"id": "cam0", "source": str(video), "reference": "config.png"},
                   {"id": "cam1", "source": str(video), "reference": "config.png"}],
        "zones": {"file": str(cell)}, "service": {"capacity_check": "off"}},
        "monitor.toml", tmp_path)
    pipeline, *_ = build_pipeline(config)
    used = pipeline.cameras["cam0"].health._reference
    assert np.array_equal(used, cv2.imread(str(zone_ref)))
    assert np.array_equal(pipeline.cameras["cam1"].health._reference,
                          cv2.imread(str(tmp_path / "config.png")))
    image(zone_ref, width=80)  # replaced by hand since
    with pytest.raises(ConfigError, match=r"camera 'cam0' reference .* is 80x48, the camera is "
                       r"64x48"):
        build_pipeline(config)


def test_reference_capture_writes_the_image_and_names_it_in_the_zone_file(cell, tmp_path,
                                                                          capsys):
    frame = np.full((48, 64, 3), 100, np.uint8)
    video = tmp_path / "cam.mp4"
    write_video(video, iter([(frame, None)] * 4), 10.0)
    wrong = tmp_path / "wrong.mp4"
    write_video(wrong, iter([(np.zeros((96, 128, 3), np.uint8), None)] * 2), 10.0)
    before = cell.read_bytes()
    # no reference named yet and no --out: refused, nothing written
    assert cli.main(["reference", "capture", "--zones", str(cell), "--camera", "cam1",
                     "--source", str(video)]) == 2
    assert "has no reference yet" in one_line_error(capsys)
    out = tmp_path / "refs" / "cam1.png"
    assert cli.main(["reference", "capture", "--zones", str(cell), "--camera", "cam1",
                     "--source", str(wrong), "--out", str(out)]) == 2
    assert "is 128x96, the camera is 64x48" in one_line_error(capsys)
    assert not out.exists() and cell.read_bytes() == before
    assert cli.main(["reference", "capture", "--zones", str(cell), "--camera", "cam1",
                     "--source", str(video), "--out", str(out), "--frames", "3"]) == 0
    assert cv2.imread(str(out)).shape == (48, 64, 3)
    assert zn.load_cell(cell).cameras["cam1"].reference == "../refs/cam1.png"
    # again without --out: the zone file's path is the one written; the file is not rewritten
    saved = cell.read_bytes()
    out.unlink()
    assert cli.main(["reference", "capture", "--zones", str(cell), "--camera", "cam1",
                     "--source", str(video), "--frames", "1"]) == 0
    assert out.is_file() and cell.read_bytes() == saved
