"""The suite's own runner settings (pyproject.toml's pytest options) on a crushed machine: a
worker killed mid-test (pytest-timeout's thread method ends the worker on a hang; the kernel
may kill one) must fail that test by name, and the run must go on and end with a summary.

pytest-xdist's ``loadfile`` scheduler did not: it ran the crashed test again on each
replacement worker until ``--max-worker-restart`` was spent and dropped the rest of the run
(and, with two crashes close together, ended in an INTERNALERROR ``KeyError: <WorkerController
gwN>``: pytest-xdist issues 1189, 1362). A nested pytest run with the project's options on
three small files shows the difference."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

FILES = {
    "test_a.py": "import os, time\ndef test_a1(): pass\n"
                 "def test_a_dies(): time.sleep(0.3); os._exit(1)\ndef test_a3(): pass\n",
    "test_b.py": "import os, time\ndef test_b1(): pass\n"
                 "def test_b_dies(): time.sleep(0.3); os._exit(1)\ndef test_b3(): pass\n",
    "test_c.py": "import time\ndef test_c_hangs(): time.sleep(60)\ndef test_c2(): pass\n",
    "test_d.py": "".join(f"def test_d{i}(): pass\n" for i in range(8)),
}


@pytest.mark.slow
def test_killed_and_hung_workers_fail_their_own_tests_and_the_run_completes(tmp_path):
    options = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"][
        "ini_options"]
    for name, text in FILES.items():
        (tmp_path / name).write_text(text)
    # the project's runner options; a short timeout stands in for the 480 s
    (tmp_path / "pytest.ini").write_text(
        f"[pytest]\naddopts = {options['addopts']}\ntimeout = 3\n"
        f"timeout_method = {options['timeout_method']}\n")
    proc = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=170)
    out = proc.stdout + proc.stderr
    assert "INTERNALERROR" not in out, out[-3000:]
    summary = out.strip().splitlines()[-1]
    # every test ran once: the three that took their worker down failed, by name
    assert re.search(r"\b3 failed, 13 passed\b", summary), out[-3000:]
    failed = sorted(re.findall(r"^FAILED (\S+)", out, re.M))
    assert failed == ["test_a.py::test_a_dies", "test_b.py::test_b_dies",
                      "test_c.py::test_c_hangs"], out[-3000:]
    assert proc.returncode == 1
