"""``monitor zones``: round trip (edits in this process, checks in a fresh one), calibration,
preview, refused edits."""

from __future__ import annotations

import contextlib
import io
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from monitor import cli
from monitor import geometry as geo
from monitor import zones as zn
from tests.helpers import run_here, run_monitor

DEMO = Path(__file__).resolve().parents[1] / "zones" / "demo-cell.yaml"
ROOT = Path(__file__).resolve().parents[1]


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """One ``monitor zones ...`` command in a fresh process (the zone commands' own entry point,
    the same ``register`` the ``monitor`` command uses)."""
    return run_monitor("zones", *args, cwd=cwd, timeout=60)


def ok(*args: str, cwd: Path) -> str:
    """One ``monitor zones ...`` command in a fresh process; its output on success."""
    res = run(*args, cwd=cwd)
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    return res.stdout


def ok_here(*args: str, cwd: Path) -> str:
    """The same command in this process (the ``main`` a fresh process runs, without its ~1 s
    start-up); its output on success."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.chdir(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(["zones", *args])
    assert code == 0, err.getvalue()
    return out.getvalue()


def demo_pairs(noise_px: float = 0.0, n: int = 8, seed: int = 0) -> np.ndarray:
    """Image-to-floor pairs of the demo camera: u, v, x, y."""
    r, t = geo.look_at((0, -6.0, 3.2), (0, 0, 0.8))
    cam = geo.CameraModel.pinhole(1280, 720, np.array([[900.0, 0, 640], [0, 900.0, 360],
                                                       [0, 0, 1]]), None, r, t)
    rng = np.random.default_rng(seed)
    floor = rng.uniform(-2.5, 2.5, size=(n, 2))
    px, _ = cam.project(np.c_[floor, np.zeros(n)])
    return np.c_[px + rng.normal(0, noise_px, px.shape) if noise_px else px, floor]


def main(*args: str) -> int:
    return cli.main(["zones", *args])


@pytest.mark.slow
def test_round_trip_leaves_a_valid_file_and_preview_draws(tmp_path):
    f = "cell.yaml"
    ok_here("new", f, "--camera", "cam0", "--size", "1280x720", "--name", "test cell",
            cwd=tmp_path)
    pairs = " ".join(",".join(f"{v:.6f}" for v in row) for row in demo_pairs())
    out = ok_here("calibrate", f, "--camera", "cam0", "--pairs", pairs, cwd=tmp_path)
    assert "reprojection error: RMS 0.000 px" in out
    ok_here("add", f, "stop-img", "500,400 800,400 780,540 480,540", "--kind", "protective",
            cwd=tmp_path)
    ok_here("add", f, "slow-img", "100,300 1200,300 1200,700 100,700", "--kind", "warning",
            "--speed-scale", "0.4", "--anchor", "share", "--min-share", "0.3", cwd=tmp_path)
    ok_here("add", f, "stop-box", "--box=-1,-1,0,1,1,2.2", "--kind", "protective", cwd=tmp_path)
    ok_here("add", f, "slow-ring", "--extrude=-2.5,-2.5 2.5,-2.5 2.5,2.5 -2.5,2.5", "--z",
            "0,2.2",
            "--kind", "warning", "--speed-scale", "0.3", cwd=tmp_path)
    ok_here("add", f, "pillar", "--cylinder=2,2,0.3,0,3", "--kind", "watch", cwd=tmp_path)
    ok_here("add", f, "poster", "40,80 140,80 140,260 40,260", "--kind", "mask", cwd=tmp_path)
    ok_here("edit", f, "stop-img", "--points", "520,400 800,400 780,540 500,540", "--name",
            "Press",
            cwd=tmp_path)
    ok_here("edit", f, "pillar", "--new-id", "column", "--cylinder", "2,2,0.35,0,3", cwd=tmp_path)
    ok_here("disable", f, "slow-img", cwd=tmp_path)
    ok_here("remove", f, "poster", cwd=tmp_path)
    table = ok_here("list", f, cwd=tmp_path)
    assert "stop-img" in table and "column" in table and "poster" not in table
    row = next(line.split() for line in table.splitlines() if line.startswith("slow-img"))
    assert row[:3] == ["slow-img", "warning", "no"]
    shown = ok_here("show", f, "stop-img", cwd=tmp_path)
    assert "name: Press" in shown and "[520.0, 400.0]" in shown
    assert "ok: 5 zones (4 enabled), 1 camera," in ok("validate", f, cwd=tmp_path)

    cell = zn.load_cell(tmp_path / f)
    assert [z.id for z in cell.zones] == ["stop-img", "slow-img", "stop-box", "slow-ring",
                                          "column"]
    assert cell.zone("column").radius_m == 0.35 and not cell.zone("slow-img").enabled
    assert ok_here("hash", f, cwd=tmp_path).strip() == cell.config_hash
    assert (tmp_path / "cell.yaml.bak").is_file()

    frame = np.random.default_rng(0).integers(0, 256, (720, 1280, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "frame.png"), frame)
    ok_here("preview", f, "--frame", "frame.png", "--out", "out/preview.png", "--hit", "stop-box",
            cwd=tmp_path)
    drawn = cv2.imread(str(tmp_path / "out" / "preview.png"))
    assert drawn.shape == frame.shape
    assert np.any(drawn[470, 650] != frame[470, 650])  # inside stop-img
    inside_mask = np.zeros((720, 1280), np.uint8)
    cv2.fillPoly(inside_mask, [np.array([[520, 400], [800, 400], [780, 540], [500, 540]])], 1)
    changed = np.any(drawn != frame, axis=2)
    assert changed[inside_mask == 1].mean() > 0.95
    assert changed[5:60, 1150:1275].any()  # the legend (top right) names the kinds
    assert not changed[300:330, 1150:1275].any()  # a strip no zone or legend reaches


def test_refused_edit_is_one_line_exit_2_and_file_unchanged(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_bytes(DEMO.read_bytes())
    before = path.read_bytes()
    res = run("add", "cell.yaml", "robot-warning", "10,10 50,10 50,50", "--kind", "mask",
              cwd=tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip() == ("monitor: error: cell.yaml: zone 'robot-warning': duplicate "
                                  "zone id")
    assert path.read_bytes() == before and not (tmp_path / "cell.yaml.bak").exists()


@pytest.mark.parametrize("args, fragment", [
    pytest.param(["add", "cell.yaml", "x", "0,0 100,100 100,0 0,100", "--kind", "protective"],
                 "self-intersecting", id="self-intersecting"),
    pytest.param(["add", "cell.yaml", "x", "0,0 100,0 100,100", "--kind", "protective",
                  "--camera", "cam3"], "unknown camera 'cam3'", id="unknown-camera"),
    pytest.param(["add", "cell.yaml", "x", "0,0 1300,0 100,100", "--kind", "mask"],
                 "outside the 1280x720 image", id="outside-image"),
    pytest.param(["add", "cell.yaml", "x", "--box=0,0,2,1,1,1", "--kind", "protective"],
                 "z_min >= z_max", id="z-order"),
    pytest.param(["add", "cell.yaml", "x", "--mesh", "none.stl", "--kind", "protective"],
                 "not found", id="mesh-missing"),
    pytest.param(["add", "cell.yaml", "x", "--extrude=0,0 1,0 1,1", "--z", "0,2", "--kind",
                  "warning"], "needs speed_scale", id="no-speed-scale"),
    pytest.param(["edit", "cell.yaml", "nope", "--name", "x"], "no zone 'nope'", id="no-zone"),
    pytest.param(["remove", "cell.yaml", "nope"], "no zone 'nope'", id="remove-missing"),
    pytest.param(["calibrate", "cell.yaml", "--camera", "cam0", "--pairs",
                  "0,0,0,0 100,0,1,0 0,100,0,1"], "at least 4 point pairs", id="three-pairs"),
    pytest.param(["calibrate", "cell.yaml", "--camera", "cam0", "--pairs",
                  "0,0,0,0 100,0,1,0 200,0,2,0 0,100,0,1"], "degenerate", id="degenerate"),
    pytest.param(["new", "cell.yaml", "--camera", "c", "--size", "10x10"], "file exists",
                 id="new-exists"),
])
def test_faulty_commands_write_nothing(tmp_path, monkeypatch, capsys, args, fragment):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "cell.yaml"
    path.write_bytes(DEMO.read_bytes())
    before = path.read_bytes()
    assert main(*args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("monitor: error: ") and fragment in err and "\n" not in err
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.yaml"]


def test_calibrate_from_csv_with_noise_reports_small_error(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main("new", "c.yaml", "--camera", "cam0", "--size", "1280x720") == 0
    rows = demo_pairs(noise_px=0.5, n=12, seed=3)
    lines = ["u,v,x,y"] + [",".join(f"{v:.4f}" for v in r) for r in rows]
    (tmp_path / "pairs.csv").write_text("\n".join(lines) + "\n")
    capsys.readouterr()
    assert main("calibrate", "c.yaml", "--camera", "cam0", "--csv", "pairs.csv") == 0
    out = capsys.readouterr().out
    rms = float(out.split("RMS ")[1].split(" px")[0])
    assert 0.05 < rms < 2.0
    cell = zn.load_cell(tmp_path / "c.yaml")
    floor, valid = cell.camera_models["cam0"].pixel_to_floor(np.array([[640.0, 531.97]]))
    assert valid[0] and np.linalg.norm(floor[0] - [0, -1]) < 0.05


def test_calibrate_warns_naming_the_worst_pair_above_2_px(tmp_path, monkeypatch, capsys):
    """One pair with its floor point 0.3 m off (a mistyped coordinate): the fit absorbs part of
    it, the RMS goes past 2 px, and calibrate says so on stderr naming that pair."""
    monkeypatch.chdir(tmp_path)
    assert main("new", "c.yaml", "--camera", "cam0", "--size", "1280x720") == 0
    rows = demo_pairs(n=10, seed=3)
    rows[6, 2] += 0.3
    pairs = " ".join(",".join(f"{v:.6f}" for v in r) for r in rows)
    capsys.readouterr()
    assert main("calibrate", "c.yaml", "--camera", "cam0", "--pairs", pairs) == 0
    out, err = capsys.readouterr()
    rms = float(out.split("RMS ")[1].split(" px")[0])
    assert rms > 2.0
    (line,) = [x for x in err.splitlines() if "likely wrong" in x] or [err]
    assert line.startswith("monitor: warning: ") and "pair 7 (" in line, err
    # a good calibration says nothing
    pairs = " ".join(",".join(f"{v:.6f}" for v in r) for r in demo_pairs(n=10, seed=3))
    assert main("calibrate", "c.yaml", "--camera", "cam0", "--pairs", pairs) == 0
    assert "RMS" not in capsys.readouterr().err


def test_calibrate_pnp_recovers_the_demo_extrinsics(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "c.yaml"
    path.write_bytes(DEMO.read_bytes())
    rows = demo_pairs(n=10, seed=5)
    pairs = " ".join(",".join(f"{v:.9f}" for v in r) for r in rows)
    assert main("calibrate", "c.yaml", "--camera", "cam0", "--pnp", "--pairs", pairs) == 0
    assert "RMS 0.000 px" in capsys.readouterr().out
    cal = zn.load_cell(path).cameras["cam0"].calibration
    r, t = geo.look_at((0, -6.0, 3.2), (0, 0, 0.8))
    np.testing.assert_allclose(np.array(cal.rotation), r, atol=1e-6)
    np.testing.assert_allclose(np.array(cal.translation_m), t, atol=1e-5)


def test_calibrate_dry_run_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "c.yaml"
    path.write_bytes(DEMO.read_bytes())
    pairs = " ".join(",".join(f"{v:.6f}" for v in r) for r in demo_pairs())
    assert main("calibrate", "c.yaml", "--camera", "cam0", "--pairs", pairs, "--dry-run") == 0
    assert path.read_bytes() == DEMO.read_bytes()


def test_validate_prints_every_fault(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    text = DEMO.read_text().replace("z_max_m: 2.2", "z_max_m: -1.0").replace(
        "camera: cam0\n    anchor: bottom-centre\n    points_px: [[40.0",
        "camera: cam5\n    anchor: bottom-centre\n    points_px: [[40.0")
    (tmp_path / "c.yaml").write_text(text)
    assert main("validate", "c.yaml") == 2
    err = capsys.readouterr().err.splitlines()
    assert any("zone 'robot-warning': z_min >= z_max" in e for e in err)
    assert any("zone 'poster-mask': unknown camera 'cam5'" in e for e in err)


def test_demo_file_validates_and_previews(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main("validate", str(DEMO)) == 0
    assert "ok: 6 zones (6 enabled)" in capsys.readouterr().out
    cv2.imwrite("f.png", np.full((720, 1280, 3), 90, np.uint8))
    assert main("preview", str(DEMO), "--frame", "f.png", "--out", "p.png") == 0
    drawn = cv2.imread("p.png")
    assert np.any(drawn[1100 // 5, 1100] != 90)  # the shelf watch zone (x 1000..1200, y 220)
    assert np.any(drawn[600, 640] != 90)  # the warning area on the floor


def test_edits_keep_the_files_comments_and_layout(tmp_path):
    import difflib

    f = tmp_path / "cell.yaml"
    f.write_text(DEMO.read_text())
    assert main("add", str(f), "door", "900,400 1000,400 1000,600 900,600", "--kind", "warning",
                "--speed-scale", "0.5") == 0
    diff = list(difflib.unified_diff(DEMO.read_text().splitlines(), f.read_text().splitlines(),
                                     lineterm="", n=0))
    removed = [ln for ln in diff[2:] if ln.startswith("-") and ln.strip("- ")]
    assert removed == [], removed  # adding a zone only adds lines (blank lines may go)
    assert (tmp_path / "cell.yaml.bak").read_text() == DEMO.read_text()
    assert main("disable", str(f), "shelf-watch") == 0
    text = f.read_text()
    for comment in ("# person model: vertical cylinder standing on the floor",
                    "# the OTUS tracker report's (ZČU Plzeň 2018) calibrated offset on the flange",
                    "# look-at from eye (0, -6.0, 3.2) to target (0, 0, 0.8), up +z"):
        assert comment in text
    assert "- [900.0, 400.0]" in text  # points in flow style, one per line
    cell = zn.load_cell(f)
    assert cell.zone("door").kind == "warning" and not cell.zone("shelf-watch").enabled


def test_zones_add_takes_the_points_after_an_option_too(tmp_path):
    """`zones add FILE ID --kind K 'x,y ...'` used to fail with "unrecognized arguments"."""
    cell = tmp_path / "cell.yaml"
    cell.write_bytes(DEMO.read_bytes())
    pts = "10,10 200,10 200,200 10,200"
    first = run_here("zones", "add", cell, "late", "--kind", "protective", pts)
    assert first.returncode == 0, first.stderr
    assert run_here("zones", "add", cell, "early", pts, "--kind", "protective").returncode == 0
    shown = run_here("zones", "show", cell, "late").stdout
    assert "200" in shown
    # a second leftover is still refused in one line
    bad = run_here("zones", "add", cell, "twice", "--kind", "protective", pts, pts)
    assert bad.returncode == 2 and "unrecognized arguments" in bad.stderr
