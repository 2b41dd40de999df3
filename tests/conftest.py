"""Shared fixtures: the synthetic model is built once per test session into a temp dir."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.shared import built_once


@pytest.fixture(scope="session")
def synthetic_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from monitor.models import synthetic

    def build(folder: Path) -> Path:
        path = folder / "tiny-yolov3-synthetic.onnx"
        synthetic.write_model(path)
        prepare_backends(path)
        return path

    return built_once(tmp_path_factory, "synthetic-model", build)


def prepare_backends(path: Path) -> None:
    """With more backends than onnxruntime here (the [openvino] extra), measure `auto`'s
    choice for the shared model once, at the thread counts the tests' configs use, and the
    envelope with the chosen backend: as a deployed monitor's later starts, the tests' `monitor
    run`s then open it at once instead of each first one measuring (tens of seconds on a loaded
    host, before the bus opens). tests/test_backends.py measures on its own copies."""
    from monitor.detector import DetectorConfig
    from monitor.detector.choice import open_detector
    from monitor.detector.envelope import for_detector
    from monitor.detector.runners import available, model_facts

    if len(available(model_facts(path))) == 1:
        return
    for threads in (1, 2):
        det, _ = open_detector(path, DetectorConfig(threads=threads, backend_budget_s=600))
        for_detector(det, 0.9)


@pytest.fixture(scope="session")
def detector(synthetic_model: Path):
    from monitor.detector import Detector, DetectorConfig

    # one inference thread: the suite's three workers share two cores, and two threads each
    # make more that wait on each other (measured: ~17 % fewer frames per second in all)
    return Detector(synthetic_model, DetectorConfig(threads=1))


@pytest.fixture(autouse=True)
def _isolated_home(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch):
    """Keep the model cache of CLI runs out of the user's home."""
    home = tmp_path_factory.getbasetemp() / "monitor-home"
    monkeypatch.setenv("WORKCELL_MONITOR_HOME", str(home))


def pytest_configure(config: pytest.Config) -> None:
    """Files the tests write get the usual 0644/0755: a umask of 002 (group-writable files)
    would make the monitor refuse the operators and public key files they write.

    Bytecode is written even where PYTHONDONTWRITEBYTECODE is set (as on some CI hosts): the
    suite starts `monitor` in a few hundred fresh processes, and each would otherwise compile
    the package from source again (0.55 s of CPU a start, measured), as would each worker its
    assertion-rewritten test modules."""
    import os
    import sys

    os.umask(0o022)
    sys.dont_write_bytecode = False
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
