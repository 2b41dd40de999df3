"""Static int8 quantization: the synthetic model and a YOLOv8-shaped export, the CLI's check
against fp32 on held-out frames, and its one-line refusals."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
from monitor.models import synthetic
from onnx import TensorProto, helper, numpy_helper

from monitor import quantize
from monitor.accuracy import Accuracy, cell_tolerance_px, score_frame
from monitor.detector import Detector
from monitor.scene import random_frames

SIZE = (768, 432)  # small frames, 256 model input: the tests stay quick


def run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "monitor", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout)


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


def test_head_nodes_are_the_last_convolutions_and_after(model256):
    keep = quantize.head_nodes(onnx.load(str(model256)))
    assert set(keep) == {"out13", "conv15", "out26", "conv22"}


# ----------------------------------------------------------------------------- a YOLOv8 export


def yolov8_like(path: Path, size: int = 256, seed: int = 0) -> Path:
    """A small graph shaped like an Ultralytics YOLOv8 export: SiLU convolutions, a box branch
    with a grid of anchor points, sigmoid class scores, output 1x84xN. Channel 0 carries
    "bright square here"; the other channels hold random weights like a trained model's."""
    rng = np.random.default_rng(seed)
    g = size // 8
    inits, nodes = [], []

    def init(name, array):
        inits.append(numpy_helper.from_array(np.asarray(array, np.float32), name))
        return name

    def silu(x, name):
        nodes.append(helper.make_node("Sigmoid", [x], [f"{name}.sig"], name=f"{name}.sig"))
        nodes.append(helper.make_node("Mul", [x, f"{name}.sig"], [f"{name}.act"],
                                      name=f"{name}.mul"))
        return f"{name}.act"

    w1 = rng.normal(0, 0.05, (16, 3, 8, 8))
    w1[0] = 1.0 / (3 * 64)
    b1 = rng.normal(0, 0.1, 16)
    b1[0] = -0.5
    nodes.append(helper.make_node("Conv", ["images", init("w1", w1), init("b1", b1)], ["c1"],
                                  name="c1", kernel_shape=[8, 8], strides=[8, 8]))
    a1 = silu("c1", "c1")
    w2 = rng.normal(0, 0.05, (16, 16, 3, 3))
    w2[0] = 0.0
    w2[0, 0, 1, 1] = 4.0
    nodes.append(helper.make_node("Conv", [a1, init("w2", w2), init("b2", np.zeros(16))], ["c2"],
                                  name="c2", kernel_shape=[3, 3], pads=[1, 1, 1, 1]))
    a2 = silu("c2", "c2")
    wc = rng.normal(0, 0.05, (80, 16, 1, 1))
    wc[0] = 0.0
    wc[0, 0] = 20.0
    nodes.append(helper.make_node("Conv", [a2, init("wc", wc), init("bc", np.full(80, -8.0))],
                                  ["cls.logit"], name="cls", kernel_shape=[1, 1]))
    nodes.append(helper.make_node("Sigmoid", ["cls.logit"], ["cls.score"], name="cls.sig"))
    nodes.append(helper.make_node("Reshape", ["cls.score", init("shape80", [1, 80, g * g])],
                                  ["cls.flat"], name="cls.flat"))
    inits[-1] = numpy_helper.from_array(np.array([1, 80, g * g], np.int64), "shape80")
    wb = np.zeros((2, 16, 1, 1))
    nodes.append(helper.make_node("Conv", [a2, init("wb", wb), init("bb", [16.0, 16.0])],
                                  ["wh"], name="box.wh", kernel_shape=[1, 1]))
    nodes.append(helper.make_node("Reshape", ["wh", "shape2"], ["wh.flat"], name="wh.flat"))
    inits.append(numpy_helper.from_array(np.array([1, 2, g * g], np.int64), "shape2"))
    yy, xx = np.mgrid[0:g, 0:g]
    grid = np.stack([xx.ravel(), yy.ravel()])[None] * 8.0 + 4.0
    nodes.append(helper.make_node("Concat", [init("anchor_points", grid), "wh.flat"], ["box"],
                                  axis=1, name="box"))
    nodes.append(helper.make_node("Concat", ["box", "cls.flat"], ["output0"], axis=1,
                                  name="head"))
    graph = helper.make_graph(
        nodes, "yolov8_like",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, size, size])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 84, g * g])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    entry = model.metadata_props.add()
    entry.key, entry.value = "names", str({i: ("person" if i == 0 else f"c{i}")
                                           for i in range(80)})
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def bright_squares(n: int, seed: int, size: int = 512) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(n):
        img = rng.normal(60, 6, (size, size, 3)).clip(0, 255).astype(np.uint8)
        for _ in range(int(rng.integers(1, 3))):
            s = int(rng.integers(90, 150))
            x, y = (int(v) for v in rng.integers(0, size - s, 2))
            img[y:y + s, x:x + s] = 235
        frames.append(img)
    return frames


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
