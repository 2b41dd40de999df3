"""The backend seam and the choice (monitor/detector/runners.py, choice.py): every backend this
host has finds the same persons as onnxruntime on the demo frames, ``auto`` never runs an
unavailable or disagreeing backend, a disagreeing or uncheckable backend is refused in one
line, and a missing ``[openvino]`` extra is one line. Real runtimes throughout: the tests that
need OpenVINO run where the extra is installed (CI installs it) and the rest run everywhere
(CI also runs this file in an environment without it)."""

from __future__ import annotations

import dataclasses
import itertools
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from monitor.models import synthetic

from monitor.detector import Detector, DetectorConfig, quantize
from monitor.detector.choice import (
    BackendRefused,
    Trial,
    cache_path,
    decide,
    open_detector,
    refusal,
)
from monitor.detector.runners import (
    OPENVINO_MISSING,
    REFERENCE,
    BackendUnavailable,
    Candidate,
    available,
    model_facts,
    open_runner,
    openvino_installed,
)
from monitor.scene import DemoScene, random_frames
from tests.helpers import run_here

needs_openvino = pytest.mark.skipif(not openvino_installed(),
                                    reason="the [openvino] extra is not installed")
ONNX = Candidate(REFERENCE, "fp32")
OV_BF16 = Candidate("openvino", "bf16")
OV_FP32 = Candidate("openvino", "fp32")


@pytest.fixture(scope="module")
def demo_frames() -> list[np.ndarray]:
    """Every 12th of the demo walk's 360 frames: the person outside, in the warning and in
    the protective zone."""
    return [image for image, _ in itertools.islice(DemoScene().frames(), 0, 360, 12)]


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    """The synthetic model in its own folder: the choice caches beside it."""
    path = tmp_path_factory.mktemp("backends") / "tiny-yolov3-synthetic.onnx"
    synthetic.write_model(path)
    return path


@pytest.fixture(scope="module")
def int8_model(model: Path) -> Path:
    calib = [f for f, _ in random_frames(8, seed=1000, size=(1280, 720))]
    return quantize.quantize_model(model, model.with_name("m.int8.onnx"), calib,
                                   quantize.QuantizeOptions(ranges=synthetic.int8_ranges()))


def agreement(model_path: Path, candidate: Candidate, frames) -> quantize.Agreement:
    reference = Detector(model_path, DetectorConfig(threads=1))
    other = Detector(model_path, DetectorConfig(threads=1),
                     runner=open_runner(model_path, candidate, 1))
    assert other.backend.backend == candidate.backend
    return quantize.compare(reference, other, frames)


def test_every_available_backend_finds_the_same_persons_on_the_demo(model, demo_frames):
    """Within the criteria of `monitor model quantize` (persons matched at IoU 0.5, found by
    both / by either >= 0.98), on the whole walk, for every backend and precision here."""
    cands = available(model_facts(model))
    assert cands[0] == ONNX
    assert (OV_FP32 in cands) == openvino_installed()
    for cand in cands[1:]:
        a = agreement(model, cand, demo_frames)
        assert a.fp32_persons >= 10, a  # the walk has a person in half of them
        assert quantize.check_agreement(a, 0.98) is None, (cand, a.table())
        assert a.min_iou > 0.9, (cand, a.table())


@needs_openvino
def test_openvino_runs_the_int8_model_like_onnxruntime(int8_model, demo_frames):
    cands = available(model_facts(int8_model))
    assert cands[0] == Candidate(REFERENCE, "int8")
    assert Candidate("openvino", "int8") in cands
    assert Candidate("openvino", "bf16") not in cands  # an int8 model runs int8
    a = agreement(int8_model, Candidate("openvino", "int8"), demo_frames)
    assert quantize.check_agreement(a, 0.98) is None, a.table()


def test_the_reference_runs_without_any_extra(model):
    """A plain Detector (and ``backend = "onnxruntime"``) is onnxruntime on the CPU at the
    model's precision, and says so."""
    det = Detector(model, DetectorConfig(threads=1))
    assert det.backend == ONNX
    det, choice = open_detector(model, DetectorConfig(threads=1, backend="onnxruntime"))
    assert det.backend == ONNX and choice.chosen == ONNX and not choice.trials


@pytest.mark.slow
def test_auto_picks_only_an_available_agreeing_backend_and_caches_it(model):
    config = DetectorConfig(threads=1, backend_budget_s=600)  # every one measured, loaded or not
    cache_path(model).unlink(missing_ok=True)
    det, choice = open_detector(model, config)
    labels = {c.label for c in available(model_facts(model))}
    assert det.backend == choice.chosen and choice.chosen.label in labels
    assert "detector backend " + choice.chosen.label in choice.line()
    for trial in choice.trials:
        assert trial.candidate.label in labels
    if choice.chosen != ONNX:  # it agreed on the figures and beat onnxruntime by the margin
        trial = next(t for t in choice.trials if t.candidate == choice.chosen)
        assert trial.refused is None and trial.agreement.agreement >= 0.98
        assert trial.speed_ratio <= 0.9
    if openvino_installed():
        assert cache_path(model).is_file() and not choice.cached
        again, second = open_detector(model, config)
        assert second.cached and second.chosen == choice.chosen
        assert again.backend == choice.chosen
    else:  # nothing but onnxruntime: nothing measured, nothing stored
        assert choice.chosen == ONNX and not choice.trials


@pytest.fixture(scope="module")
def fragile(model: Path) -> Path:
    """A model whose persons vanish in bf16 (tests/onnx_models.py: bf16_fragile)."""
    from tests.onnx_models import bf16_fragile

    return bf16_fragile(model, model.with_name("fragile.onnx"))


@needs_openvino
def test_a_backend_that_disagrees_is_refused_and_auto_never_runs_it(fragile):
    """A real disagreement: OpenVINO bf16 loses every person of this model. `auto` refuses it
    naming the figures and runs an agreeing backend; named, it is one line at start."""
    if OV_BF16 not in available(model_facts(fragile)):
        pytest.skip("this CPU has no bf16")
    config = DetectorConfig(threads=1, backend_budget_s=600)
    det, choice = open_detector(fragile, config)
    bf16 = next(t for t in choice.trials if t.candidate == OV_BF16)
    # every person of every figure missed (the figures: the self-test image's shifts and
    # each grade of each envelope axis, glare included)
    missed = bf16.agreement.fp32_only
    assert missed > 0 and bf16.refused == (
        "openvino bf16 agrees with onnxruntime on 0.000 of the persons (below 0.98): "
        f"{missed} missed, 0 extra, of {missed} on {bf16.agreement.frames} self-test and "
        "envelope figures"), bf16
    assert choice.chosen != OV_BF16 and det.backend != OV_BF16
    assert "openvino bf16 refused (openvino bf16 agrees with onnxruntime on 0.000" \
        in choice.line()
    cfg = fragile.with_name("monitor.toml")
    cfg.write_text('[detector]\nbackend = "openvino"\nprecision = "bf16"\nthreads = 1\n')
    line = one_line(run_here("model", "info", "--model", fragile, "--config", cfg))
    assert line == ("monitor: error: [detector] backend 'openvino' bf16 refused: openvino "
                    f"bf16: {bf16.refused}")


def trial(cand: Candidate, ms: float, persons: tuple[int, int, int] = (40, 40, 40),
          refused: str | None = None) -> Trial:
    a = quantize.Agreement(51, persons[0], persons[1], persons[2], 0.99, 0.95, 20.0, ms)
    return Trial(cand, ms, 20.0, a, "self-test and envelope figures", refused)


def test_auto_never_picks_a_refused_backend_however_fast():
    """decide() is the rule ``open_detector`` applies to its measured trials."""
    config = DetectorConfig()
    fast_wrong = trial(OV_BF16, 5.0, (40, 38, 38), refused="agrees on 0.950 of the persons")
    slower_right = trial(OV_FP32, 15.0)
    assert decide(ONNX, [fast_wrong, slower_right], {}, config, True)[0] == OV_FP32
    # refused on the user's frames (monitor model check-backend): never, whatever the figures
    frames = {"openvino fp32": trial(OV_FP32, 15.0, refused="missed 3 of your frames")}
    assert decide(ONNX, [fast_wrong, slower_right], frames, config, True)[0] == ONNX
    # not measurably faster than onnxruntime: onnxruntime
    assert decide(ONNX, [trial(OV_FP32, 19.0)], {}, config, True)[0] == ONNX
    # never compared (no self-test image) and not checked on the user's frames: onnxruntime
    unchecked = dataclasses.replace(trial(OV_BF16, 5.0), agreement=None)
    assert decide(ONNX, [unchecked], {}, config, False)[0] == ONNX
    passed = {"openvino bf16": trial(OV_BF16, 5.0)}
    assert decide(ONNX, [unchecked], passed, config, False)[0] == OV_BF16


def test_a_named_backend_that_disagrees_is_refused_naming_the_figures():
    a = quantize.Agreement(51, 40, 37, 37, 0.99, 0.9, 20.0, 5.0)
    why = refusal(a, 0.98, "openvino bf16", "self-test and envelope figures")
    assert why == ("openvino bf16 agrees with onnxruntime on 0.925 of the persons (below "
                   "0.98): 3 missed, 0 extra, of 40 on 51 self-test and envelope figures")
    config = DetectorConfig(backend="openvino", precision="bf16")
    with pytest.raises(BackendRefused) as err:
        decide(ONNX, [trial(OV_BF16, 5.0, (40, 37, 37), refused=why)], {}, config, True)
    assert str(err.value) == f"[detector] backend 'openvino' bf16 refused: openvino bf16: {why}"
    assert "\n" not in str(err.value)


def config_file(tmp_path: Path, detector: str) -> Path:
    path = tmp_path / "monitor.toml"
    path.write_text(f"[detector]\n{detector}\n")
    return path


def one_line(proc: subprocess.CompletedProcess) -> str:
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    return lines[0]


@needs_openvino
def test_a_named_backend_without_a_self_test_image_is_refused_in_one_line(tmp_path):
    """A model of the user's without a self-test image cannot be checked on the figures: a
    named other backend is refused (at `monitor run` and `model info` alike) until its frames
    pass `monitor model check-backend`."""
    from tests.onnx_models import yolov8_like

    model = yolov8_like(tmp_path / "v8.onnx")
    cfg = config_file(tmp_path, 'backend = "openvino"\nprecision = "fp32"')
    line = one_line(run_here("model", "info", "--model", model, "--config", cfg))
    assert line.startswith("monitor: error: [detector] backend 'openvino' fp32 refused: "
                           "openvino fp32: no self-test image to check it on"), line


def test_check_backend_refuses_on_frames_without_persons(tmp_path, model):
    """Frames in which onnxruntime finds nobody check nothing: every other backend is refused
    there (exit 1, one line each naming the figures), and the refusal is recorded."""
    own = tmp_path / model.name  # its own cache: the other tests' model is not refused
    own.write_bytes(model.read_bytes())
    model = own
    frames = tmp_path / "empty"
    frames.mkdir()
    for i in range(8):
        cv2.imwrite(str(frames / f"{i}.png"), np.full((360, 640, 3), 100 + i, np.uint8))
    proc = run_here("model", "check-backend", "--model", model, "--frames", frames)
    if not openvino_installed():
        assert proc.returncode == 0 and "nothing to check" in proc.stdout
        return
    assert proc.returncode == 1, proc.stderr
    refused = [ln for ln in proc.stderr.splitlines() if ln.startswith("refused:")]
    assert refused and all("onnxruntime finds no person in the 8 of your frames" in ln
                           for ln in refused), proc.stderr
    record = json.loads(cache_path(model).read_text())
    frames_part = next(iter(record["entries"].values()))["frames"]
    assert all("refused" in t for t in frames_part.values())
    # and `auto` then never runs them, whatever the figures said
    det, choice = open_detector(model, DetectorConfig(threads=1))
    assert choice.chosen == ONNX and det.backend == ONNX


@needs_openvino
def test_check_backend_on_the_demo_walk_agrees(tmp_path, model):
    video = tmp_path / "walk.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 15, (1280, 720))
    for image, _ in itertools.islice(DemoScene().frames(), 60, 240, 6):
        writer.write(image)
    writer.release()
    proc = run_here("model", "check-backend", "--model", model, "--frames", video,
                    "--backend", "openvino")
    assert proc.returncode == 0, proc.stderr
    rows = [ln for ln in proc.stdout.splitlines() if ln.startswith("| openvino")]
    assert len(rows) >= 1 and all("| agrees |" in r for r in rows), proc.stdout


MISSING = """
import sys
sys.modules["openvino"] = None  # as if the [openvino] extra were not installed
from monitor import cli
sys.exit(cli.main(sys.argv[1:]))
"""


def test_a_missing_openvino_extra_is_one_clear_line(tmp_path, model):
    cfg = config_file(tmp_path, 'backend = "openvino"')
    proc = subprocess.run([sys.executable, "-c", MISSING, "model", "info", "--model",
                           str(model), "--config", str(cfg)], capture_output=True, text=True,
                          timeout=300)
    assert one_line(proc) == f"monitor: error: {OPENVINO_MISSING}"
    # and `auto` without it runs onnxruntime, the only backend there
    cfg = config_file(tmp_path, 'backend = "auto"\nthreads = 1')
    proc = subprocess.run([sys.executable, "-c", MISSING, "model", "info", "--model",
                           str(model), "--config", str(cfg)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "onnxruntime fp32 (the reference; the only backend here)" in proc.stdout


def test_an_unknown_backend_or_device_is_one_line(tmp_path, model):
    cfg = config_file(tmp_path, 'backend = "tensorflow"')
    line = one_line(run_here("model", "info", "--model", model, "--config", cfg))
    assert "backend" in line and "tensorflow" in line
    with pytest.raises(BackendUnavailable, match="CUDAExecutionProvider"):
        open_runner(model, Candidate("onnxruntime-cuda", "auto"), 1)


@needs_openvino
@pytest.mark.slow
def test_the_envelope_is_measured_with_the_backend_that_runs(model):
    from monitor.detector import envelope as env

    det = Detector(model, DetectorConfig(threads=1), runner=open_runner(model, OV_BF16, 1))
    assert env.backend_tag(det) == "openvino-bf16"
    measured = env.for_detector(det, 0.9)
    assert env.sidecar_path(model, "openvino-bf16").is_file()
    reference = env.for_detector(Detector(model, DetectorConfig(threads=1)), 0.9)
    assert env.limits_of(measured) == env.limits_of(reference)  # it agreed on those figures


def test_status_metrics_and_capacity_name_the_backend():
    from prometheus_client import generate_latest

    from monitor.cli.status_text import status_text
    from monitor.detector.choice import Choice
    from monitor.service.capacity import Limits, cameras_served
    from monitor.service.metrics import Metrics

    choice = Choice(OV_BF16, (trial(OV_BF16, 8.0), trial(OV_FP32, 21.0)),
                    "2.50x faster than onnxruntime here", reference=ONNX)
    status = {"detector": choice.to_dict()}
    assert ("detector backend: openvino bf16, agreement 1.000 with onnxruntime (2.50x faster "
            "than onnxruntime here)") in status_text(status).splitlines()
    assert "detector backend: unknown (not reported)" in status_text({}).splitlines()
    metrics = Metrics(0, "127.0.0.1")
    metrics.set_backend("openvino", "bf16", 1.0)
    text = generate_latest(metrics.registry).decode()
    assert 'monitor_detector_backend{backend="openvino",precision="bf16"} 1.0' in text
    assert "monitor_detector_backend_agreement 1.0" in text
    # the capacity per backend: a faster detector serves at least as many cameras
    limits = Limits(0.5, 0.3, 0.5, 1.0)
    fast, slow = cameras_served(0.010, 1920, 1080, 10.0, limits), \
        cameras_served(0.040, 1920, 1080, 10.0, limits)
    assert fast[0] >= slow[0] >= 1 and fast[1] == pytest.approx(10.0)
    assert cameras_served(2.0, 1920, 1080, 10.0, limits) == (0, 0.0)


@pytest.mark.slow
def test_monitor_run_says_which_backend_runs(tmp_path):
    """The start-up line of `monitor run` (the embedded demo) names the backend, its
    precision and agreement."""
    from tests.helpers import run_monitor

    proc = run_monitor("run", "--duration", "2", timeout=400)
    assert proc.returncode == 0, proc.stderr[-2000:]
    line = next((ln for ln in proc.stderr.splitlines() if "INFO detector backend " in ln), "")
    labels = [c.label for c in available(model_facts(synthetic.ensure_model()))]
    assert any(f"detector backend {label} (" in line for label in labels), proc.stderr[-3000:]
