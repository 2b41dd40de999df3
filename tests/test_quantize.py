"""Static int8 quantization: the synthetic model and a YOLOv8-shaped export, the CLI's check
against fp32 on held-out frames, and its one-line refusals."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
from monitor.models import synthetic
from onnx import TensorProto

from monitor.detector import Detector, quantize
from monitor.scene import random_frames
from monitor.scene.accuracy import Accuracy, cell_tolerance_px, score_frame
from tests.helpers import run_monitor
from tests.onnx_models import bright_squares, yolov8_like

SIZE = (768, 432)  # small frames, 256 model input: the tests stay quick


def run(*args: object, timeout: float = 300) -> subprocess.CompletedProcess:
    return run_monitor(*args, timeout=timeout)  # quantizing takes longer than other commands


def one_line_error(proc: subprocess.CompletedProcess) -> str:
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[-1]


@pytest.fixture(scope="module")
def model256(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("q") / "synthetic256.onnx"
    synthetic.write_model(path, input_size=256)
    return path


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory) -> Path:
    """16 generated frames with persons, written as PNG files (a user's frame directory)."""
    out = tmp_path_factory.mktemp("frames")
    frames = (f for f, t in random_frames(60, seed=7, size=SIZE) if t.persons)
    for i, image in zip(range(16), frames, strict=False):
        cv2.imwrite(str(out / f"frame{i:03d}.png"), image)
    return out


@pytest.mark.slow
def test_int8_synthetic_model_agrees_with_fp32_and_ground_truth(tmp_path, model256):
    calib = [f for f, _ in random_frames(8, seed=1000, size=SIZE)]
    int8_path = quantize.quantize_model(
        model256, tmp_path / "m.int8.onnx", calib,
        quantize.QuantizeOptions(ranges=synthetic.int8_ranges()))
    fp32, int8 = Detector(model256), Detector(int8_path)
    held = list(random_frames(16, seed=5, size=SIZE))
    agreement = quantize.compare(fp32, int8, [f for f, _ in held])
    assert agreement.fp32_persons > 15
    assert agreement.recall >= 0.98 and agreement.precision >= 0.98, agreement.table()
    assert agreement.min_iou > 0.8
    tol = cell_tolerance_px(SIZE, 256)
    acc = Accuracy()
    for image, truth in held:
        score_frame(int8.detect(image).boxes_px, truth, tol, acc)
    assert acc.recall >= 0.98 and acc.precision >= 0.98
    assert acc.distractor_hits == 0
    # quantized convolutions: the file holds int8 weights, and the heads stayed in float
    model = onnx.load(str(int8_path))
    ops = {n.op_type for n in model.graph.node}
    assert "DequantizeLinear" in ops
    floats = {i.name for i in model.graph.initializer if i.data_type == TensorProto.FLOAT}
    last = next(n for n in model.graph.node if n.name == "conv22")
    assert last.input[1] in floats  # the head's weights: float, not dequantized int8
    first = next(n for n in model.graph.node if n.name == "conv0")
    assert first.input[1] not in floats


@pytest.mark.slow
def test_cli_refuses_below_the_agreement_threshold_then_writes(tmp_path, model256, frames_dir):
    out = tmp_path / "m.int8.onnx"
    proc = run("model", "quantize", model256, "--frames", frames_dir, "--out", out,
               "--min-agreement", "1.01")
    line = one_line_error(proc)
    assert "int8 model not written" in line and "below 1.01" in line and "--force" in line
    assert not out.exists() and not list(tmp_path.glob("*.onnx"))
    assert "found by both" in proc.stdout  # the comparison table is shown anyway
    proc = run("model", "quantize", model256, "--frames", frames_dir, "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert out.is_file() and f"wrote {out}" in proc.stdout
    assert re.search(r"^fp32 only \(int8 misses\) +0$", proc.stdout, re.M), proc.stdout
    # the passed check is recorded beside it: monitor run recommends only such a file
    from monitor.service.int8hint import check_passed

    assert check_passed(out)[0], check_passed(out)[1]
    proc = run("model", "quantize", model256, "--frames", frames_dir, "--out", out,
               "--min-agreement", "1.01", "--force")
    assert proc.returncode == 0, proc.stderr
    assert not check_passed(out)[0] and "--force" in check_passed(out)[1]


def test_head_nodes_are_the_last_convolutions_and_after(model256):
    keep = quantize.head_nodes(onnx.load(str(model256)))
    assert set(keep) == {"out13", "conv15", "out26", "conv22"}


# ----------------------------------------------------------------------------- a YOLOv8 export






def test_a_yolov8_shaped_export_quantizes_and_still_decodes(tmp_path):
    fp32_path = yolov8_like(tmp_path / "v8.onnx")
    fp32 = Detector(fp32_path)
    assert fp32.layout.kind == "yolov8"
    int8_path = quantize.quantize_model(fp32_path, tmp_path / "v8.int8.onnx",
                                        bright_squares(12, seed=1))
    int8 = Detector(int8_path)
    assert int8.layout.kind == "yolov8"
    ops = [n.op_type for n in onnx.load(str(int8_path)).graph.node]
    assert ops.count("QuantizeLinear") >= 2
    agreement = quantize.compare(fp32, int8, bright_squares(8, seed=2))
    assert agreement.fp32_persons >= 8
    assert agreement.agreement >= 0.98 and agreement.min_iou > 0.7, agreement.table()


# ----------------------------------------------------------------------------- bad input


def test_bad_frames_and_models_give_one_line_errors(tmp_path, model256):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no images here")
    line = one_line_error(run("model", "quantize", model256, "--frames", empty))
    assert "no frames in" in line
    fake_video = tmp_path / "walk.mp4"
    fake_video.write_bytes(b"not a video")
    line = one_line_error(run("model", "quantize", model256, "--frames", fake_video))
    assert "cannot read video" in line
    line = one_line_error(run("model", "quantize", model256, "--frames", tmp_path / "nope"))
    assert "frames not found" in line
    not_a_model = tmp_path / "model.onnx"
    not_a_model.write_text("hello")
    line = one_line_error(run("model", "quantize", not_a_model, "--frames", empty))
    assert "cannot load model" in line


def test_too_few_frames_are_refused(tmp_path):
    with pytest.raises(quantize.InputError, match="only 3 frames"):
        quantize.split_frames([np.zeros((8, 8, 3), np.uint8)] * 3)


def test_frames_are_read_from_a_video_spread_over_it(tmp_path):
    path = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    for i in range(40):
        writer.write(np.full((48, 64, 3), i * 5, np.uint8))
    writer.release()
    frames = quantize.read_frames(path, limit=10)
    assert len(frames) == 10
    means = [float(f.mean()) for f in frames]
    assert means == sorted(means) and means[-1] - means[0] > 100  # spread over the whole video


def test_agreement_counts_misses_and_extras():
    a = quantize.Agreement(frames=4, fp32_persons=10, int8_persons=9, both=8, mean_iou=0.9,
                           min_iou=0.8, fp32_ms=20.0, int8_ms=8.0)
    assert (a.fp32_only, a.int8_only) == (2, 1)
    assert a.agreement == pytest.approx(8 / 11)
    assert "2 missed, 1 extra" in quantize.check_agreement(a, 0.98)
    none_seen = quantize.Agreement(4, 0, 0, 0, 0.0, 0.0, 1.0, 1.0)
    assert "finds no person" in quantize.check_agreement(none_seen, 0.5)
    assert quantize.match_persons(np.array([[0, 0, 10, 10], [20, 0, 30, 10]]),
                                  np.array([[21, 0, 31, 10]])) == [pytest.approx(9 / 11)]
