"""Zone-file hardening (issue 10): strict types, hostile YAML, safe saving, protective zones,
tracker_frame; and `monitor zones` calibration messages (issue 12)."""

from __future__ import annotations

import math
import os
import stat
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from monitor import cli
from monitor import geometry as geo
from monitor import zones as zn
from monitor.errors import ConfigError
from monitor.zones import separation as zsep

DEMO = Path(__file__).resolve().parents[1] / "zones" / "demo-cell.yaml"


def demo_data() -> dict:
    return zn.read_cell_data(DEMO)


def write(tmp_path: Path, data: dict, name: str = "cell.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def one_line_error(path: Path) -> str:
    with pytest.raises(ConfigError) as err:
        zn.load_cell(path)
    text = str(err.value)
    assert "\n" not in text and str(path) in text
    return text


# ---------------------------------------------------------------------------- strict types


@pytest.mark.parametrize("value, shown", [
    pytest.param("'no'", "'no'", id="quoted-no"),
    pytest.param("'off'", "'off'", id="quoted-off"),
    pytest.param("off", "'off'", id="yaml11-off"),
    pytest.param("0", "0", id="zero"),
    pytest.param("'false'", "'false'", id="quoted-false"),
])
def test_enabled_must_be_a_boolean(tmp_path, value, shown):
    text = DEMO.read_text().replace("    kind: protective\n",
                                    f"    kind: protective\n    enabled: {value}\n", 1)
    path = tmp_path / "cell.yaml"
    path.write_text(text)
    msg = one_line_error(path)
    assert f"enabled: must be true or false (got {shown})" in msg


@pytest.mark.parametrize("section, key", [
    ("person", "radius_m"), ("separation", "reaction_time_s"), ("separation",
                                                                 "programmed_speed_mps"),
])
def test_quoted_numbers_are_refused(tmp_path, section, key):
    data = demo_data()
    data[section][key] = "0.3"
    msg = one_line_error(write(tmp_path, data))
    assert f"{section}: {key}: must be a number, not str '0.3'" in msg


def test_a_boolean_is_not_a_number_and_a_float_width_is_not_an_int(tmp_path):
    data = demo_data()
    data["person"]["height_m"] = True
    assert "height_m: must be a number, not bool" in one_line_error(write(tmp_path, data))
    data = demo_data()
    data["cameras"][0]["width"] = 1280.0
    assert "camera 'cam0': width: must be a number" in one_line_error(write(tmp_path, data))


def test_true_false_and_integers_for_floats_still_load(tmp_path):
    data = demo_data()
    data["zones"][0]["enabled"] = False
    data["person"]["radius_m"] = 1  # an int where a float is wanted is a number
    cell = zn.load_cell(write(tmp_path, data))
    assert cell.spec.person.radius_m == 1.0 and not cell.zones[0].enabled


# ---------------------------------------------------------------------------- hostile YAML


@pytest.mark.parametrize("text, expected", [
    pytest.param("version: 1\n[1]: 2\n", "a key must be a plain name", id="unhashable-key"),
    pytest.param("version: !!float abc\n", "YAML value cannot be read", id="bad-float-tag"),
    pytest.param("version: 1\nname: !!timestamp 2001-99-99\n", "YAML value cannot be read",
                 id="bad-timestamp"),
    pytest.param("x: " + "[" * 3000 + "]" * 3000 + "\n", "nested 3000 deep", id="deep"),
    pytest.param("a:\n" + "".join(" " * (i + 1) + f"a{i}:\n" for i in range(3000))
                 + " " * 3001 + "1\n", "nested more than 64 levels", id="deep-block"),
    pytest.param("version: 1\nversion: 1\n", "duplicate key 'version'", id="duplicate"),
    pytest.param("a: [1\n", "YAML syntax error", id="syntax"),
    pytest.param("\xff\xfe", "cannot read zone file", id="not-utf8"),
])
def test_every_yaml_problem_is_a_one_line_config_error(tmp_path, text, expected):
    path = tmp_path / "bad.yaml"
    path.write_bytes(text.encode("latin-1") if text.startswith("\xff") else text.encode())
    msg = one_line_error(path)
    assert expected in msg
    with pytest.raises(ConfigError) as err:  # the round-trip reader of the edit commands too
        zn.parse_cell(zn.read_cell_document(path), path)
    assert "\n" not in str(err.value)


def test_a_timestamp_where_text_is_wanted_is_a_field_error(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(DEMO.read_text().replace("name: demo-cell", "name: 2001-12-14"))
    assert "name: Input should be a valid string" in one_line_error(path)


def test_a_typo_in_the_only_camera_names_the_key_not_a_missing_camera(tmp_path):
    data = demo_data()
    data["cameras"][0]["widht"] = data["cameras"][0].pop("width")
    errors, _ = zn.cell_faults(data)
    assert "camera 'cam0': unknown field 'widht'" in errors
    assert "camera 'cam0': missing field 'width'" in errors
    assert not any("at least one camera" in e for e in errors)
    data["cameras"] = []
    errors, _ = zn.cell_faults(data)
    assert errors == ["cameras: at least one camera is needed"]


def test_validate_lists_4000_faults_each_with_its_zone():
    """4,000 faults used to take 3 minutes (the error list was rebuilt per message); the time is
    measured by benchmarks/zone_files.py, this checks the messages."""
    data = demo_data()
    base = data["zones"][0]
    data["zones"] = [dict(base, id=f"z{i}", bogus=1) for i in range(4000)]
    errors, _ = zn.cell_faults(data)
    assert errors == [f"zone 'z{i}': unknown field 'bogus'" for i in range(4000)]


# ---------------------------------------------------------------------------- protective zones


def test_has_protective_zone_and_the_validate_warning():
    cell = zn.load_cell(DEMO)
    assert cell.has_protective_zone
    data = demo_data()
    for z in data["zones"]:
        if z["kind"] == "protective":
            z["enabled"] = False
    cell = zn.parse_cell(data, DEMO)
    assert not cell.has_protective_zone
    assert any("no enabled protective zone" in w for w in cell.warnings)
    data["zones"] = []
    assert not zn.parse_cell(data, DEMO).has_protective_zone


# ---------------------------------------------------------------------------- safe saving


def test_save_keeps_mode_and_leaves_no_temp_file(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(DEMO.read_text())
    os.chmod(path, 0o640)
    cell = zn.load_cell(path)
    zn.save_cell(cell, path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.yaml", "cell.yaml.bak"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes read-only files anyway")
def test_a_read_only_file_or_directory_is_refused_in_one_line(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(DEMO.read_text())
    cell = zn.load_cell(path)
    os.chmod(path, 0o444)
    with pytest.raises(ConfigError, match="read-only: not replaced"):
        zn.save_cell(cell, path)
    os.chmod(path, 0o644)
    os.chmod(tmp_path, 0o555)
    try:
        with pytest.raises(ConfigError, match="cannot write zone file"):
            zn.save_cell(cell, path)
    finally:
        os.chmod(tmp_path, 0o755)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.yaml"]
    assert path.read_text() == DEMO.read_text()


def test_a_read_only_file_is_refused_even_for_root(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(DEMO.read_text())
    os.chmod(path, 0o444)
    with pytest.raises(ConfigError, match="read-only"):
        zn.save_cell(zn.load_cell(path), path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o444


def test_a_failed_write_removes_its_temp_file_and_keeps_the_old_one(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(DEMO.read_text())
    cell = zn.load_cell(path)

    class Boom(KeyboardInterrupt):
        pass

    real = os.fsync

    def interrupted(fd):
        raise Boom()

    os.fsync = interrupted
    try:
        with pytest.raises(Boom):
            zn.save_cell(cell, path)
    finally:
        os.fsync = real
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.yaml"]
    assert path.read_text() == DEMO.read_text()


def test_stale_temp_files_of_a_killed_run_are_removed(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(DEMO.read_text())
    stale = tmp_path / ".cell.yaml.abc123.tmp"
    fresh = tmp_path / ".cell.yaml.def456.tmp"
    other = tmp_path / ".other.yaml.abc123.tmp"
    for p in (stale, fresh, other):
        p.write_text("partial")
    old = time.time() - 3600
    os.utime(stale, (old, old))
    os.utime(other, (old, old))
    zn.save_cell(zn.load_cell(path), path)
    assert not stale.exists()
    assert fresh.exists() and other.exists()  # a parallel save, another file: left alone


# ---------------------------------------------------------------------------- tracker_frame


def test_tracker_frame_moves_the_tool_into_the_cell():
    data = demo_data()
    cell = zn.parse_cell(data, DEMO)
    data["tracker_frame"] = {"translation_m": [1.0, -0.5, 0.2], "rpy_deg": [0.0, 0.0, 90.0]}
    framed = zn.parse_cell(data, DEMO)
    assert framed.config_hash != cell.config_hash
    pose = geo.ToolPose((0.5, 0.0, 0.8), (0.0, 0.0, 0.0, 1.0), 0.0)
    moved = zsep.pose_in_cell(framed.prepared, pose)
    np.testing.assert_allclose(moved.position_m, [1.0, 0.0, 1.0], atol=1e-12)
    assert zsep.pose_in_cell(cell.prepared, pose) is pose
    # the check uses the cell pose: same separation as the moved pose without a frame
    boxes = np.array([[600.0, 200.0, 660.0, 500.0]])
    a = zn.check_persons(framed, "cam0", boxes, tool_pose=pose, tool_speed_mps=0.0)
    b = zn.check_persons(cell, "cam0", boxes, tool_pose=moved, tool_speed_mps=0.0)
    assert a.tool_separation_m == pytest.approx(b.tool_separation_m, abs=1e-9)
    data["tracker_frame"]["rpy_deg"] = ["90", 0, 0]
    with pytest.raises(ConfigError, match=r"tracker_frame: rpy_deg\.0: must be a number"):
        zn.parse_cell(data, DEMO)


def test_quaternion_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        back = geo.matrix_to_quaternion_xyzw(geo.quaternion_to_matrix(q))
        np.testing.assert_allclose(geo.quaternion_to_matrix(back), geo.quaternion_to_matrix(q),
                                   atol=1e-12)


# ---------------------------------------------------------------------------- CLI


def test_calibrate_with_four_pairs_says_the_fit_cannot_be_checked(tmp_path, capsys):
    path = tmp_path / "cell.yaml"
    path.write_text(DEMO.read_text())
    r, t = geo.look_at((0, -6.0, 3.2), (0, 0, 0.8))
    cam = geo.CameraModel.pinhole(1280, 720, np.array([[900.0, 0, 640], [0, 900.0, 360],
                                                       [0, 0, 1]]), None, r, t)
    floor = np.array([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0], [0.0, 0.5],
                      [1.0, -1.0]])
    px, _ = cam.project(np.c_[floor, np.zeros(len(floor))])
    wrong = np.c_[px, floor]
    wrong[1, 0] += 40  # a wrong pair: 4 pairs cannot show it
    pairs = " ".join(",".join(f"{v:.6f}" for v in row) for row in wrong[:4])
    assert cli.main(["zones", "calibrate", str(path), "--camera", "cam0", "--pairs", pairs,
                     "--dry-run"]) == 0
    out = capsys.readouterr()
    assert "RMS 0.000 px" in out.out
    assert "4 pairs leave no redundancy" in out.err and "Give 6 or more pairs" in out.err
    pairs = " ".join(",".join(f"{v:.6f}" for v in row) for row in wrong)
    assert cli.main(["zones", "calibrate", str(path), "--camera", "cam0", "--pairs", pairs,
                     "--dry-run"]) == 0
    out = capsys.readouterr()
    assert "redundancy" not in out.err
    assert "RMS 0.000 px" not in out.out  # 6 pairs show the wrong one


def test_validate_reports_the_horizon(tmp_path, capsys):
    assert cli.main(["zones", "validate", str(DEMO)]) == 0
    out = capsys.readouterr().out
    assert "camera 'cam0': horizon at row 0 (centre column): floor below it" in out


def test_every_zones_option_documents_its_default(capsys):
    import argparse

    from monitor.cli.zones import register

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    zones = parser._subparsers._group_actions[0].choices["zones"]
    actions = zones._subparsers._group_actions[0].choices
    missing = []
    for name, sub in actions.items():
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            text = action.help or ""
            if not text or (action.option_strings and "default" not in text
                            and "required" not in text):
                missing.append(f"{name} {action.dest}")
    assert missing == []


def test_calibrate_tool_writes_offset_and_frame(tmp_path, capsys):
    from tests.tool_poses import MOUNT, REFERENCE, pose_pairs

    path = tmp_path / "cell.yaml"
    path.write_text(DEMO.read_text())
    flange, tracker = pose_pairs(np.random.default_rng(2), 40, 0.5, 0.3)
    rows = []
    for a, b in zip(flange, tracker, strict=True):
        qa = geo.matrix_to_quaternion_xyzw(a[:3, :3])
        qb = geo.matrix_to_quaternion_xyzw(b[:3, :3])
        rows.append(",".join(f"{v:.9f}" for v in (*a[:3, 3], *qa, *b[:3, 3], *qb)))
    csv_path = tmp_path / "poses.csv"
    csv_path.write_text("fx,fy,fz,fqx,fqy,fqz,fqw,tx,ty,tz,tqx,tqy,tqz,tqw\n"
                        + "\n".join(rows) + "\n")
    assert cli.main(["zones", "calibrate-tool", str(path), "--csv", str(csv_path)]) == 0
    out = capsys.readouterr().out
    assert "residual_mm" in out and out.count("\n") > 40
    cell = zn.load_cell(path)
    off = cell.spec.tool.offset
    assert off.given_as == "tracker_in_tool"
    np.testing.assert_allclose(np.array(off.translation_mm) / 1000, MOUNT[:3, 3], atol=1e-3)
    frame = cell.spec.tracker_frame.cell_from_tracker()
    np.testing.assert_allclose(frame[:3, 3], REFERENCE[:3, 3], atol=3e-3)
    assert geo.rotation_angle_deg(frame[:3, :3].T @ REFERENCE[:3, :3]) < 0.5
    # mixed-up pairs: residuals too large, nothing written
    before = path.read_text()
    shuffled = rows[5:] + rows[:5]  # tracker poses paired with the wrong flange poses
    mixed = [",".join(r.split(",")[:7] + s.split(",")[7:])
             for r, s in zip(rows, shuffled, strict=True)]
    csv_path.write_text("\n".join(mixed) + "\n")
    assert cli.main(["zones", "calibrate-tool", str(path), "--csv", str(csv_path)]) == 2
    assert "exceeds" in capsys.readouterr().err
    assert path.read_text() == before


def test_non_finite_values_never_reach_the_separation(tmp_path):
    data = demo_data()
    data["separation"]["programmed_speed_mps"] = float("nan")
    assert "programmed_speed_mps" in one_line_error(write(tmp_path, data))
    assert not math.isnan(zn.load_cell(DEMO).spec.separation.programmed_speed_mps)


def test_image_zone_beyond_the_horizon_is_refused():
    # a feet-anchored protective polygon must lie on the floor side of the camera's horizon
    import copy

    from monitor.config import demo_cell_path

    data = copy.deepcopy(zn.read_cell_data(demo_cell_path()))
    cam = data["cameras"][0]
    cam["calibration"]["camera_matrix"][1][2] = 560.0  # principal point lower: horizon at ~200
    cell = zn.parse_cell(data)
    cam_id = cam["id"]
    row = cell.camera_models[cam_id].horizon_row_px()
    assert row is not None and 150 < row < 250
    data["zones"].append({"id": "sky", "kind": "protective", "shape": "polygon",
                          "camera": cam_id,
                          "points_px": [[100, 1], [300, 1], [300, row + 50], [100, row + 50]]})
    errors, _ = zn.cell_faults(data)
    assert any("zone 'sky'" in e and "horizon" in e for e in errors), errors
    with pytest.raises(ConfigError, match="beyond camera"):
        zn.parse_cell(data)
