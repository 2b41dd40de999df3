"""The layers of monitor/ are a contract ([tool.importlinter] in pyproject.toml,
docs/architecture.md "Layers"): `lint-imports` keeps them on the real tree and refuses an
upward import."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LINT = Path(sys.executable).with_name("lint-imports")


def _lint(tree: Path) -> subprocess.CompletedProcess:
    """`lint-imports` on the package under ``tree`` with the project's contracts."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.run([str(LINT), "--no-cache", "--config", str(ROOT / "pyproject.toml")],
                          cwd=tree, env=env, capture_output=True, text=True, timeout=120)


def test_the_real_tree_keeps_every_contract():
    run = _lint(ROOT)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Contracts: 4 kept, 0 broken." in run.stdout


def test_an_upward_import_in_a_copy_fails_naming_it(tmp_path):
    shutil.copytree(ROOT / "monitor", tmp_path / "monitor",
                    ignore=shutil.ignore_patterns("__pycache__", "static", "*.yaml"))
    machine = tmp_path / "monitor" / "policy" / "machine.py"
    # the policy (a building block) reaching up into the pipeline that runs it
    machine.write_text(machine.read_text() + "\nfrom monitor.pipeline import Pipeline  # noqa\n")
    run = _lint(tmp_path)
    out = run.stdout + run.stderr
    assert run.returncode != 0, out
    assert "monitor.policy is not allowed to import monitor.pipeline" in out, out
    assert "monitor.policy.machine -> monitor.pipeline" in out, out
    # the same import closes a circle the acyclic contract names too
    assert "no import circles among the modules of any package BROKEN" in out, out


def test_a_circle_inside_a_package_even_for_the_type_checker_fails_naming_it(tmp_path):
    """The acyclic contract covers every level, not only monitor's children, and imports a type
    checker follows: volumes -> files closes files -> prepare -> volumes inside monitor.zones."""
    shutil.copytree(ROOT / "monitor", tmp_path / "monitor",
                    ignore=shutil.ignore_patterns("__pycache__", "static", "*.yaml"))
    volumes = tmp_path / "monitor" / "zones" / "volumes.py"
    volumes.write_text(volumes.read_text() + "\nfrom typing import TYPE_CHECKING\n\n"
                       "if TYPE_CHECKING:\n    from monitor.zones.files import Cell  # noqa\n")
    run = _lint(tmp_path)
    out = run.stdout + run.stderr
    assert run.returncode != 0, out
    assert "no import circles among the modules of any package BROKEN" in out, out
    assert "No cycles are allowed in monitor.zones." in out, out
