"""Detector outputs that change shape at run time (an extra dimension, no rows, another batch):
each is a named detector fault, never "no persons". The models are real ONNX graphs run by
onnxruntime: an ``If`` on the frame's brightness gives the layout's normal output on dark frames
(the load-time probe, the warm-up) and the odd one on bright frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from monitor.detector import Detector, DetectorConfig
from monitor.errors import DetectorError
from tests.onnx_models import FRAME_H, FRAME_W, INPUT, PERSONS, C, cxcywh, to_input

CELLS = (INPUT // 8) ** 2 + (INPUT // 16) ** 2 + (INPUT // 32) ** 2
DARK = np.full((FRAME_H, FRAME_W, 3), 40, np.uint8)
BRIGHT = np.full((FRAME_H, FRAME_W, 3), 250, np.uint8)


def _rows(n: int = 3 * CELLS) -> np.ndarray:
    """YOLOv5 rows (cx cy w h obj classes) with the two test persons."""
    rows = np.zeros((1, n, 5 + C), np.float32)
    for i, box in enumerate(PERSONS if n else ()):
        rows[0, 10 * i] = [*cxcywh(to_input(box)), 0.9, 0.95, 0.0, 0.0]
    return rows


def switching_model(path: Path, normal: np.ndarray, bright: np.ndarray,
                    batch: int | str = 1) -> Path:
    """Output ``normal`` for a dark input, ``bright`` when the input's maximum is over 0.5."""
    def branch(name: str, value: np.ndarray):
        node = helper.make_node("Constant", [], [f"{name}_out"],
                                value=numpy_helper.from_array(value, f"{name}_value"))
        return helper.make_graph([node], name, [], [
            helper.make_tensor_value_info(f"{name}_out", TensorProto.FLOAT, None)])

    nodes = [
        helper.make_node("ReduceMax", ["images"], ["peak"], keepdims=0),
        helper.make_node("Greater", ["peak", "half"], ["bright"]),
        helper.make_node("If", ["bright"], ["output0"], then_branch=branch("odd", bright),
                         else_branch=branch("normal", normal)),
    ]
    graph = helper.make_graph(
        nodes, "switching",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [batch, 3, INPUT, INPUT])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, ["b", "rows", "cols"])],
        [numpy_helper.from_array(np.array(0.5, np.float32), "half")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, path)
    return path


def _detector(path: Path) -> Detector:
    return Detector(path, DetectorConfig(input_size=INPUT, merge_touch_px=-1))


@pytest.mark.parametrize("odd", [
    pytest.param(_rows()[None], id="extra-dimension"),
    pytest.param(_rows(0), id="no-rows"),
    pytest.param(np.concatenate([np.zeros_like(_rows()), _rows()]), id="two-batches"),
    pytest.param(_rows(3 * CELLS - 1), id="one-row-short"),
])
def test_an_output_in_another_shape_is_a_named_detector_fault(tmp_path, odd):
    detector = _detector(switching_model(tmp_path / "m.onnx", _rows(), odd))
    assert detector.layout.kind == "yolov5"
    assert len(detector.detect(DARK)) == 2  # the normal output: both persons
    with pytest.raises(DetectorError, match=r"output 'output0' has shape .* found at load"):
        detector.detect(BRIGHT)


def test_end_to_end_detections_may_be_none_but_not_another_shape(tmp_path):
    e2e = np.zeros((1, 10, 6), np.float32)
    e2e[0, 0] = [*to_input(PERSONS[0]), 0.9, 0]
    empty = np.zeros((1, 0, 6), np.float32)  # K = 0: an end-to-end export found nothing
    detector = _detector(switching_model(tmp_path / "e.onnx", e2e, empty))
    assert detector.layout.kind == "end2end"
    assert len(detector.detect(DARK)) == 1 and len(detector.detect(BRIGHT)) == 0
    odd = _detector(switching_model(tmp_path / "o.onnx", e2e, e2e[:, :, :5]))
    with pytest.raises(DetectorError, match="found at load"):
        odd.detect(BRIGHT)


def test_a_batch_answered_with_fewer_batches_is_a_named_fault(tmp_path):
    """A dynamic-batch model that answers two frames with one batch."""
    detector = _detector(switching_model(tmp_path / "b.onnx", _rows(), _rows(), batch="n"))
    assert detector.batchable
    with pytest.raises(DetectorError, match=r"expects \(2, .* for 2 frame"):
        detector.detect_batch([DARK, DARK])
