"""``monitor init``: a deployment folder from the shipped kit, taken to a running monitor with
the CLI alone (no hand edits); ``monitor docs``; the service refuses a zone on a camera that no
[[camera]] feeds."""

from __future__ import annotations

import re
import shutil
import stat
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from monitor.config import load_config
from monitor.wire.signing import load_operators, load_private_key
from tests.helpers import free_port, run_here, run_monitor

POLY = "40,40 600,40 600,440 40,440"


def ok(*args: object, cwd: Path | None = None) -> str:
    """A file command (init, zones, docs) in this process; ``monitor run`` gets its own."""
    res = run_here(*args, cwd=cwd)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "Traceback" not in res.stderr
    return res.stdout


def one_line_error(res: subprocess.CompletedProcess, *needles: str) -> str:
    errors = [ln for ln in res.stderr.strip().splitlines()
              if not ln.startswith("monitor: warning: ")]
    assert res.returncode == 2 and len(errors) == 1, res.stderr
    assert errors[0].startswith("monitor: error: ")
    for needle in needles:
        assert needle in errors[0], errors[0]
    return errors[0]


def clip(path: Path, seed: int, seconds: float = 2.0, fps: float = 10.0) -> Path:
    """A short textured video (a camera's view of a busy cell, no person)."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.integers(0, 256, (480, 640, 3), dtype=np.uint8), (5, 5), 0)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (640, 480))
    for _ in range(int(seconds * fps)):
        writer.write(base)
    writer.release()
    return path


@pytest.mark.slow
def test_init_to_a_running_two_camera_monitor_with_the_cli_alone(tmp_path):
    cam0, cam1 = clip(tmp_path / "cam0.mp4", 0), clip(tmp_path / "cam1.mp4", 1)
    first = tmp_path / "staging" / "kit"
    out = ok("init", first, "--cell", "cell7", "--camera", f"cam0={cam0}", "--operator", "anna",
             "--listen", f"tcp/127.0.0.1:{free_port()}")
    assert "next:" in out and "protective" in out
    kit = tmp_path / "etc" / "workcell-monitor"  # the folder moves as it is
    kit.parent.mkdir()
    shutil.move(first, kit)

    ok("zones", "camera", "add", kit / "cell.yaml", "cam1", "--source", cam1, "--config",
       kit / "monitor.toml")
    ok("zones", "add", kit / "cell.yaml", "stop0", POLY, "--kind", "protective", "--camera",
       "cam0")
    ok("zones", "add", kit / "cell.yaml", "stop1", POLY, "--kind", "protective", "--camera",
       "cam1")
    assert "ok: 2 zones (2 enabled), 2 cameras" in ok("zones", "validate", kit / "cell.yaml")

    config = load_config(kit / "monitor.toml")
    assert [c.id for c in config.cameras] == ["cam0", "cam1"]
    assert config.zones.file == str(kit / "cell.yaml")
    assert config.bus.signing_key == str(kit / "keys" / "monitor.key")
    assert config.bus.zenoh_config_file == str(kit / "zenoh" / "peer.json5")
    assert config.bus.cell == "cell7" and config.model.path is None

    # the kit's capacity check refuses a busy host; this test may run beside other tests
    # (tests/test_capacity.py tests the check itself)
    run = run_monitor("run", "--config", kit / "monitor.toml", "--duration", "5",
                      "--capacity-check", "warn", timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr and " ERROR " not in run.stderr
    for cam in ("cam0", "cam1"):
        assert re.search(rf"camera connected.*{cam}", run.stderr), run.stderr[-3000:]
    assert "stopped" in run.stderr


def test_init_writes_the_kit_with_private_keys_and_refuses_to_overwrite(tmp_path):
    video = clip(tmp_path / "v.mp4", 2, seconds=0.5)
    kit = tmp_path / "kit"
    ok("init", kit, "--camera", f"cam0={video}", "--operator", "anna", "--operator", "ben",
       "--commissioner", "carla")
    for name in ("monitor.toml", "cell.yaml", "workcell-monitor.service", "operators",
                 "commissioners",
                 "zenoh/peer.json5", "zenoh/router-secure.json5", "zenoh/client-secure.json5"):
        assert (kit / name).is_file(), name
    for key in ("monitor", "anna", "ben", "carla"):
        assert stat.S_IMODE((kit / "keys" / f"{key}.key").stat().st_mode) == 0o600
        load_private_key(kit / "keys" / f"{key}.key")
    assert stat.S_IMODE((kit / "keys").stat().st_mode) == 0o700
    assert set(load_operators(kit / "operators")) == {"anna", "ben"}  # never carla: one role
    assert set(load_operators(kit / "commissioners")) == {"carla"}
    assert load_config(kit / "monitor.toml").service.commissioners_file == \
        str(kit / "commissioners")
    assert "ExecStart=" in (kit / "workcell-monitor.service").read_text()

    before = {p: p.read_bytes() for p in kit.rglob("*") if p.is_file()}
    again = run_here("init", kit, "--camera", f"cam0={video}")
    one_line_error(again, "exists", "--force")
    assert {p: p.read_bytes() for p in kit.rglob("*") if p.is_file()} == before
    ok("init", kit, "--camera", f"cam0={video}", "--force")
    assert (kit / "keys" / "monitor.key").read_bytes() != before[kit / "keys" / "monitor.key"]


def test_init_with_a_live_camera_leaves_the_model_to_the_integrator(tmp_path):
    res = run_here("init", tmp_path / "a", "--camera", "cam0=rtsp://10.0.0.21/stream1")
    one_line_error(res, "--size")
    assert not (tmp_path / "a").exists()
    out = ok("init", tmp_path / "b", "--camera", "cam0=rtsp://10.0.0.21/stream1", "--size",
             "1280x720")
    assert "[model] path" in out
    config = load_config(tmp_path / "b" / "monitor.toml")
    assert config.model.path is None and not config.model.allow_test_model
    assert config.camera.source == "rtsp://10.0.0.21/stream1" and not config.camera.loop
    assert "# path = " in (tmp_path / "b" / "monitor.toml").read_text()


def test_run_refuses_a_zone_on_a_camera_no_config_camera_feeds(tmp_path):
    """A camera added to the zone file but not to monitor.toml: its protective zone would
    never see anyone; the service must not start as if the cell were watched."""
    video = clip(tmp_path / "v.mp4", 3)
    kit = tmp_path / "kit"
    ok("init", kit, "--camera", f"cam0={video}", "--listen", f"tcp/127.0.0.1:{free_port()}")
    ok("zones", "camera", "add", kit / "cell.yaml", "cam1", "--size", "640x480")
    ok("zones", "add", kit / "cell.yaml", "stop0", POLY, "--kind", "protective", "--camera",
       "cam0")
    ok("zones", "add", kit / "cell.yaml", "stop1", POLY, "--kind", "protective", "--camera",
       "cam1")
    res = run_monitor("run", "--config", kit / "monitor.toml", "--duration", "3")
    one_line_error(res, "zone 'stop1'", "camera 'cam1'", "no [[camera]]")


def test_docs_lists_and_prints_the_shipped_documents():
    listing = ok("docs")
    for name in ("consumer", "security", "zones", "policy"):
        assert re.search(rf"^{name}\s", listing, re.MULTILINE), listing
    assert ok("docs", "security").startswith("# ")
    assert "monitor zones camera" in ok("docs", "zones")
    one_line_error(run_here("docs", "nope"), "no document 'nope'", "consumer")


def test_run_help_points_to_monitor_init_not_to_a_checkout_file():
    text = ok("run", "-h")
    assert "monitor init" in text and "deploy/" not in text


def test_kit_in_the_wheel_list_ships_every_deploy_and_doc_file():
    """package-data globs that miss a file would leave it out of the wheel silently."""
    import tomllib
    from fnmatch import fnmatch

    root = Path(__file__).resolve().parents[1]
    setup = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    for package, folder in (("monitor.deploy", "deploy"), ("monitor.docs", "docs")):
        assert setup["package-dir"][package] == folder and package in setup["packages"]
        globs = setup["package-data"][package]
        for f in (root / folder).rglob("*"):
            if f.is_file():
                rel = f.relative_to(root / folder).as_posix()
                assert any(fnmatch(rel, g) for g in globs), f"{folder}/{rel} not shipped"


@pytest.mark.parametrize("listen, connect", [
    pytest.param(None, "tcp/127.0.0.1:7447", id="default"),
    pytest.param("tcp/0.0.0.0:7555", "tcp/127.0.0.1:7555", id="all-interfaces"),
])
def test_the_watch_hint_names_the_cell_and_the_endpoint(tmp_path, listen, connect):
    cam = clip(tmp_path / "cam0.mp4", 0, seconds=0.5)
    out = ok("init", tmp_path / "kit", "--cell", "cell7", "--camera", f"cam0={cam}",
             *(("--listen", listen) if listen else ()))
    hint = next(ln for ln in out.splitlines() if "try it:" in ln)
    assert f"monitor watch --cell cell7 --connect {connect} --monitor-key" in hint, hint
