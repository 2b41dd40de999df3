"""The installed product, not the checkout: build the wheel, install it into a fresh virtual
environment outside the source tree, and run the default service there.

The dependencies are not downloaded again: the new environment sees this environment's
site-packages through a path file (not as a site dir, so this checkout's editable install is
not active there), and the test checks that `monitor` is imported from the new environment.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.helpers import free_port

ROOT = Path(__file__).resolve().parents[1]


def test_packaged_demo_cell_is_the_example_in_zones():
    from monitor.config import demo_cell_path

    packaged = demo_cell_path()
    assert packaged.parent.name == "data" and packaged.parent.parent.name == "monitor"
    assert packaged.read_bytes() == (ROOT / "zones" / "demo-cell.yaml").read_bytes()


def test_every_package_of_the_source_tree_is_in_the_wheel_list():
    """An explicit package list forgets new subpackages silently: the wheel would lack them."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
                 ["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts)
             for p in (ROOT / "monitor").rglob("__init__.py")}
    assert found - listed == set(), "add these to [tool.setuptools] packages in pyproject.toml"



def _run(args: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.slow
def test_wheel_installs_and_runs_outside_the_checkout(tmp_path):
    src = tmp_path / "src"
    shutil.copytree(ROOT, src, symlinks=True, ignore=shutil.ignore_patterns(
        ".venv", ".git", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache",
        ".ruff_cache", ".import_linter_cache"))
    built = _run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps",
                  "--no-build-isolation", "--no-index", "--quiet", "-w", str(tmp_path / "dist")],
                 tmp_path)
    assert built.returncode == 0, built.stderr[-2000:]
    wheel = next((tmp_path / "dist").glob("workcell_monitor-*.whl"))

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = Path(_run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()"
                                          "['purelib'])"], tmp_path).stdout.strip())
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "_test_dependencies.pth").write_text("\n".join(sorted(deps)) + "\n")
    installed = _run([sys.executable, "-m", "pip", "--python", str(python), "install",
                      "--no-deps", "--no-index", "--quiet", str(wheel)], tmp_path)
    assert installed.returncode == 0, installed.stderr[-2000:]

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = _run([str(python), "-c", "import monitor, monitor.config as c; "
                  "print(monitor.__file__); print(c.demo_cell_path())"], elsewhere)
    assert where.returncode == 0, where.stderr
    module, cell = where.stdout.split()
    assert Path(module).is_relative_to(venv) and Path(cell).is_relative_to(venv)
    assert Path(cell).read_bytes() == (ROOT / "zones" / "demo-cell.yaml").read_bytes()
    # the default build's measured envelope comes with it (no 5-10 s measuring at first start)
    shipped = _run([str(python), "-c", "from monitor.models import synthetic as s; "
                    "print(s.SHIPPED_ENVELOPE.read_bytes() == open("
                    f"{str(ROOT / 'models' / 'tiny-yolov3-synthetic.onnx.envelope.json')!r}, "
                    "'rb').read())"], elsewhere)
    assert shipped.stdout.strip() == "True", shipped.stderr[-2000:]

    # `monitor run` with the demo defaults: synthetic camera, synthetic model, demo zones
    config = elsewhere / "monitor.toml"
    # capacity only warns: this test may run beside others on a loaded machine
    config.write_text(f'[bus]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'
                      '[service]\ncapacity_check = "warn"\n'
                      '[policy]\nmax_frame_age = 1.0\n')  # steps are slow on a loaded machine
    run = _run([str(venv / "bin" / "monitor"), "run", "--config", str(config), "--duration",
                "3"], elsewhere)
    assert run.returncode == 0, run.stderr[-3000:]
    started = re.search(r"started .* zones=(\S+)", run.stderr)
    assert started and Path(started.group(1)).is_relative_to(venv), run.stderr[-3000:]
    # errors other than a loaded machine's (a stall, a late frame: STOPs by design)
    errors = [line for line in run.stderr.splitlines() if " ERROR " in line
              and not re.search(r"alert (monitor_stalled|frame_late|frame_stale|camera_lost)|"
                                r"monitor stalled", line)]
    assert "Traceback" not in run.stderr and errors == [], errors
    assert "INFO stopped" in run.stderr

    helped = _run([str(venv / "bin" / "monitor"), "demo", "--help"], elsewhere)
    assert helped.returncode == 0 and "--out" in helped.stdout

    # an integrator's first day: the deploy kit and the docs come with the wheel
    video = elsewhere / "cam0.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (640, 480))
    for _ in range(5):
        writer.write(np.full((480, 640, 3), 90, np.uint8))
    writer.release()
    monitor = str(venv / "bin" / "monitor")
    init = _run([monitor, "init", "kit", "--camera", f"cam0={video}", "--operator", "anna"],
                elsewhere)
    assert init.returncode == 0, init.stderr[-3000:]
    kit = elsewhere / "kit"
    assert (kit / "monitor.toml").read_text().splitlines().count("[[camera]]") == 1
    assert (kit / "workcell-monitor.service").read_bytes() == \
        (ROOT / "deploy" / "workcell-monitor.service").read_bytes()
    for name in ("peer", "client", "router-secure", "client-secure"):
        assert (kit / "zenoh" / f"{name}.json5").read_bytes() == \
            (ROOT / "deploy" / "zenoh" / f"{name}.json5").read_bytes()
    assert (kit / "keys" / "monitor.key").is_file() and (kit / "operators").is_file()
    added = _run([monitor, "zones", "add", "kit/cell.yaml", "stop", "40,40 600,40 600,440",
                  "--kind", "protective"], elsewhere)
    assert added.returncode == 0, added.stderr
    checked = _run([str(python), "-c", "from monitor.config import load_config; "
                    f"print(load_config({str(kit / 'monitor.toml')!r}).zones.file)"], elsewhere)
    assert checked.stdout.strip() == str(kit / "cell.yaml"), checked.stderr

    listed = _run([monitor, "docs"], elsewhere)
    assert listed.returncode == 0, listed.stderr
    shipped = {p.stem for p in (ROOT / "docs").glob("*.md")} | {"zones", "model-card"}
    assert {line.split()[0] for line in listed.stdout.splitlines()[:-2] if line} == shipped
    assert str(venv) in listed.stdout.splitlines()[-1]  # read from the install, not here
    for name in ("security", "zones"):
        shown = _run([monitor, "docs", name], elsewhere)
        source = ROOT / ("zones/README.md" if name == "zones" else f"docs/{name}.md")
        assert shown.returncode == 0 and shown.stdout == source.read_text(), shown.stderr
    run_help = _run([monitor, "run", "-h"], elsewhere)
    assert "monitor init" in run_help.stdout and "deploy/" not in run_help.stdout
