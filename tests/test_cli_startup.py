"""A command imports only the module that registers it (monitor/cli/__init__.py's COMMANDS):
`monitor zones list` does not load the tracker or the detector, `monitor status` not OpenCV.
Start-up times themselves are measured, not asserted (python -X importtime; docs/performance.md)."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest

from monitor.cli import COMMAND_MODULES, COMMANDS, build_parser

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "zones" / "demo-cell.yaml"


def test_every_command_is_in_the_table_under_the_module_that_registers_it():
    registered = {}
    for module in COMMAND_MODULES:
        parser = build_parser((module,))
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        registered.update({name: module for name in sub.choices})
    assert registered == COMMANDS


def imported_by(*argv: str) -> tuple[int, set[str], str]:
    """Run the command in a fresh interpreter; (exit code, the heavy packages it imported)."""
    code = (
        "import sys, json, io, contextlib\n"
        "from monitor.cli import main\n"
        "out = io.StringIO()\n"
        "try:\n"
        "    with contextlib.redirect_stdout(out):\n"
        f"        rc = main({list(argv)!r})\n"
        "except SystemExit as e:  # --help\n"
        "    rc = e.code\n"
        "heavy = ['supervision', 'onnxruntime', 'zenoh', 'cv2', 'trimesh', 'scipy', 'av',"
        " 'starlette', 'asyncua', 'pymodbus', 'monitor.bus.session', 'monitor.frames',"
        " 'monitor.tracking.tracks']\n"
        "print(json.dumps([rc, [m for m in heavy if m in sys.modules], out.getvalue()]))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    rc, heavy, out = json.loads(proc.stdout.strip().splitlines()[-1])
    return rc, set(heavy), out


@pytest.mark.parametrize("argv, never", [
    (("zones", "list", str(DEMO)), {"supervision", "onnxruntime", "trimesh", "scipy", "av",
                                     "monitor.bus.session", "monitor.frames",
                                     "monitor.tracking.tracks"}),
    (("status", "--help"), {"supervision", "onnxruntime", "cv2", "trimesh", "scipy", "av"}),
], ids=["zones-list", "status"])
def test_a_command_loads_only_what_it_needs(argv, never):
    rc, heavy, out = imported_by(*argv)
    assert rc == 0 and ("robot-protective" in out if argv[0] == "zones" else "usage" in out)
    assert not heavy & never, f"{' '.join(argv)} imported {sorted(heavy & never)}"
