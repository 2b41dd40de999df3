"""Decoding of every output layout: small ONNX models whose outputs encode known boxes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from monitor.detector import TINY_ANCHORS, TINY_MASKS, V3_ANCHORS, V3_MASKS, Detector, letterbox
from monitor.errors import ModelError
from tests.onnx_models import (
    FRAME_H,
    FRAME_W,
    INPUT,
    OTHER,
    PAD_X,
    PAD_Y,
    PERSONS,
    SCALE,
    WEAK,
    C,
    const_model,
    cxcywh,
    darknet_heads,
    logit,
    shapeless_model,
    to_input,
    two_class_model,
)


def rows_v5() -> np.ndarray:
    rows = np.zeros((1, 20, 5 + C), np.float32)
    for i, box in enumerate(PERSONS):
        rows[0, i] = [*cxcywh(to_input(box)), 0.9, 0.95, 0.1, 0.0]
    rows[0, 2] = [*cxcywh(to_input(OTHER)), 0.9, 0.05, 0.95, 0.0]
    rows[0, 3] = [*cxcywh(to_input(WEAK)), 0.5, 0.4, 0.0, 0.0]
    return rows


def rows_e2e() -> np.ndarray:
    rows = np.zeros((1, 6, 6), np.float32)
    for i, box in enumerate(PERSONS):
        rows[0, i] = [*to_input(box), 0.88, 0]
    rows[0, 2] = [*to_input(OTHER), 0.9, 1]
    rows[0, 3] = [*to_input(WEAK), 0.2, 0]
    return rows






def yolox_rows() -> np.ndarray:
    cells = [(INPUT // s) ** 2 for s in (8, 16, 32)]
    rows = np.zeros((1, sum(cells), 5 + C), np.float32)
    for k, box in enumerate([*PERSONS, OTHER]):
        s = (8, 16, 32)[k % 3]
        offset = sum(cells[: (8, 16, 32).index(s)])
        cx, cy, w, h = cxcywh(to_input(box, pad=(0.0, 0.0)))
        gx, gy = int(cx // s), int(cy // s)
        row = offset + gy * (INPUT // s) + gx
        rows[0, row] = [cx / s - gx, cy / s - gy, math.log(w / s), math.log(h / s), 0.9,
                        0.9 if k < 2 else 0.0, 0.0 if k < 2 else 0.9, 0.0]
    return rows


def zoo_outputs() -> dict[str, np.ndarray]:
    n = 5
    boxes = np.zeros((1, n, 4), np.float32)
    scores = np.zeros((1, 80, n), np.float32)
    for i, b in enumerate([*PERSONS, OTHER]):
        boxes[0, i] = [b[1], b[0], b[3], b[2]]  # y1 x1 y2 x2, frame pixels
        scores[0, 0 if i < 2 else 1, i] = 0.9
    indices = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 2]], np.int32)
    return {"yolonms_layer_1/ExpandDims_1:0": boxes, "yolonms_layer_1/ExpandDims_3:0": scores,
            "yolonms_layer_1/concat_2:0": indices}


CASES = [
    pytest.param("yolov5", lambda: {"output0": rows_v5()}, None, {}, id="yolov5"),
    pytest.param("yolov8", lambda: {"output0": np.ascontiguousarray(
        np.delete(rows_v5(), 4, axis=2).transpose(0, 2, 1) * 1.0)}, None, {}, id="yolov8"),
    pytest.param("end2end", lambda: {"output0": rows_e2e()}, None, {}, id="end2end"),
    pytest.param("yolox", lambda: {"output": yolox_rows()}, None, {}, id="yolox"),
    pytest.param("darknet", lambda: darknet_heads([10, 20], TINY_ANCHORS, TINY_MASKS), None, {},
                 id="darknet-tiny-nchw"),
    pytest.param("darknet", lambda: darknet_heads([10, 20], TINY_ANCHORS, TINY_MASKS, nhwc=True),
                 None, {}, id="darknet-tiny-nhwc"),
    pytest.param("darknet", lambda: darknet_heads([10, 20, 40], V3_ANCHORS, V3_MASKS), None, {},
                 id="darknet-v3-3-heads"),
    pytest.param("darknet", lambda: darknet_heads([10, 20], TINY_ANCHORS, ((3, 4, 5), (0, 1, 2))),
                 None, {"masks": json.dumps([[3, 4, 5], [0, 1, 2]])}, id="darknet-masks-012"),
    pytest.param("zoo", zoo_outputs,
                 {"input_1": [1, 3, INPUT, INPUT], "image_shape": [1, 2]}, {},
                 id="zoo-tiny-yolov3"),
]


@pytest.mark.parametrize(("kind", "outputs", "inputs", "meta"), CASES)
def test_each_layout_decodes_known_boxes_in_frame_pixels(tmp_path, kind, outputs, inputs, meta):
    from monitor.detector import DetectorConfig

    path = const_model(tmp_path / "m.onnx", outputs(), inputs, meta)
    detector = Detector(path, DetectorConfig(input_size=INPUT, merge_touch_px=-1))
    assert detector.layout.kind == kind
    frame = np.full((FRAME_H, FRAME_W, 3), 100, np.uint8)
    persons = detector.detect(frame)
    got = persons.boxes_px[np.argsort(persons.boxes_px[:, 0])]
    assert got.shape == PERSONS.shape, f"{kind}: {got}"
    np.testing.assert_allclose(got, PERSONS, atol=1.0)


def test_letterbox_places_the_frame_centred_and_scaled():
    from monitor.detector import ModelLayout

    layout = ModelLayout("yolov5", "images", INPUT, INPUT)
    frame = np.zeros((FRAME_H, FRAME_W, 3), np.uint8)
    frame[:, :, 2] = 255  # red in BGR
    tensor, box = letterbox(frame, layout)
    assert tensor.shape == (1, 3, INPUT, INPUT)
    assert (box.scale, box.pad_x, box.pad_y) == (SCALE, PAD_X, PAD_Y)
    assert tensor[0, 0, 100, 100] == pytest.approx(1.0)  # R channel first
    assert tensor[0, 0, 10, 100] == pytest.approx(114 / 255)  # the pad


def test_unknown_output_layout_names_the_shapes(tmp_path):
    path = const_model(tmp_path / "odd.onnx", {"out": np.zeros((1, 7), np.float32)})
    with pytest.raises(ModelError, match=r"no known output layout.*\(1, 7\)"):
        Detector(path)


def test_missing_and_corrupt_model_files(tmp_path):
    with pytest.raises(ModelError, match="not found"):
        Detector(tmp_path / "missing.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"this is not a protobuf" * 10)
    with pytest.raises(ModelError, match="cannot load model"):
        Detector(bad)


def test_top_k_overflow_is_reported(tmp_path):
    from monitor.detector import DetectorConfig

    rows = np.zeros((1, 40, 5 + C), np.float32)
    for i in range(40):  # 40 confident persons in a row
        rows[0, i] = [10 + 7 * i, 100, 6, 20, 0.9, 0.9, 0, 0]
    detector = Detector(const_model(tmp_path / "m.onnx", {"output0": rows}),
                        DetectorConfig(input_size=INPUT, top_k=16))
    result = detector.detect_timed(np.zeros((FRAME_H, FRAME_W, 3), np.uint8))
    assert result.overflow and result.candidates == 40


# ----------------------------------------------------------------------------- layouts by evidence


def _detector(path: Path, **cfg):
    from monitor.detector import DetectorConfig

    return Detector(path, DetectorConfig(input_size=INPUT, merge_touch_px=-1, **cfg))


def _found(detector) -> np.ndarray:
    persons = detector.detect(np.full((FRAME_H, FRAME_W, 3), 100, np.uint8))
    return persons.boxes_px[np.argsort(persons.boxes_px[:, 0])]


def test_one_class_yolov5_with_three_anchors_per_cell_is_not_end_to_end(tmp_path):
    cells = (INPUT // 8) ** 2 + (INPUT // 16) ** 2 + (INPUT // 32) ** 2
    rows = np.zeros((1, 3 * cells, 6), np.float32)  # 6300 x (cx cy w h obj person)
    for i, box in enumerate(PERSONS):
        rows[0, 100 * i] = [*cxcywh(to_input(box)), 0.9, 0.95]
    detector = _detector(const_model(tmp_path / "m.onnx", {"output0": rows}))
    assert detector.layout.kind == "yolov5" and detector.layout.num_classes == 1
    np.testing.assert_allclose(_found(detector), PERSONS, atol=1.0)


def test_one_class_yolox_with_one_row_per_cell_is_not_end_to_end(tmp_path):
    cells = [(INPUT // s) ** 2 for s in (8, 16, 32)]
    rows = np.zeros((1, sum(cells), 6), np.float32)
    for k, box in enumerate(PERSONS):
        s = (16, 32)[k]
        offset = sum(cells[: (8, 16, 32).index(s)])
        cx, cy, w, h = cxcywh(to_input(box, pad=(0.0, 0.0)))
        gx, gy = int(cx // s), int(cy // s)
        rows[0, offset + gy * (INPUT // s) + gx] = [cx / s - gx, cy / s - gy, math.log(w / s),
                                                    math.log(h / s), 0.9, 0.9]
    detector = _detector(const_model(tmp_path / "m.onnx", {"output": rows}))
    assert detector.layout.kind == "yolox"
    np.testing.assert_allclose(_found(detector), PERSONS, atol=1.0)


def test_end_to_end_output_still_recognised_when_rows_match_no_grid(tmp_path):
    rows = np.zeros((1, 300, 6), np.float32)
    for i, box in enumerate(PERSONS):
        rows[0, i] = [*to_input(box), 0.8, 0]
    detector = _detector(const_model(tmp_path / "m.onnx", {"output0": rows}))
    assert detector.layout.kind == "end2end"
    np.testing.assert_allclose(_found(detector), PERSONS, atol=1.0)


def test_dynamic_axes_yolov8_is_probed(tmp_path):
    cols = np.ascontiguousarray(np.delete(rows_v5(), 4, axis=2).transpose(0, 2, 1))
    path = const_model(tmp_path / "m.onnx", {"output0": cols},
                       inputs={"images": ["batch", 3, "height", "width"]},
                       declared={"output0": ["batch", "channels", "anchors"]})
    detector = _detector(path, rectangular_input=False)
    assert detector.layout.kind == "yolov8" and not detector.layout.rect
    assert (detector.layout.input_width, detector.layout.input_height) == (INPUT, INPUT)
    np.testing.assert_allclose(_found(detector), PERSONS, atol=1.0)


def test_a_dynamic_input_whose_outputs_do_not_follow_it_runs_in_the_square(tmp_path, caplog):
    # declared dynamic, but the outputs stay the square's whatever the input (as a graph with a
    # fixed reshape inside): the rectangle would read them with the wrong grid, so the model
    # runs every frame in the full square, as its warm-up did, and says so
    cols = np.ascontiguousarray(np.delete(rows_v5(), 4, axis=2).transpose(0, 2, 1))
    path = const_model(tmp_path / "m.onnx", {"output0": cols},
                       inputs={"images": ["batch", 3, "height", "width"]},
                       declared={"output0": ["batch", "channels", "anchors"]})
    detector = _detector(path)
    assert not detector.layout.rect
    assert "declares a dynamic input size but fails at a smaller one" in caplog.text
    np.testing.assert_allclose(_found(detector), PERSONS, atol=1.0)


def test_an_output_declared_without_a_shape_is_probed(tmp_path):
    # no shape at all in the file: onnxruntime reports (), which once read as a known scalar
    cols = np.ascontiguousarray(np.delete(rows_v5(), 4, axis=2).transpose(0, 2, 1))
    path = shapeless_model(tmp_path / "m.onnx", "output0", cols)
    detector = _detector(path)
    assert detector.layout.kind == "yolov8"
    np.testing.assert_allclose(_found(detector), PERSONS, atol=1.0)


def test_a_scalar_output_is_named_in_the_error(tmp_path):
    path = shapeless_model(tmp_path / "m.onnx", "output0", np.array(0.5, np.float32))
    with pytest.raises(ModelError, match=r"output 'output0' is a scalar"):
        _detector(path)


def test_darknet_with_a_non_square_input(tmp_path):
    ih, iw = 192, 320  # like 352x608: grids 6x10 and 12x20
    scale = min(iw / FRAME_W, ih / FRAME_H)
    pad = ((iw - FRAME_W * scale) / 2, (ih - FRAME_H * scale) / 2)
    heads = {(6, 10): np.zeros((3, 5 + C, 6, 10), np.float32),
             (12, 20): np.zeros((3, 5 + C, 12, 20), np.float32)}
    for h in heads.values():
        h[:, 4] = -12.0
    for k, box in enumerate(PERSONS):
        grid, rank = ((6, 10), 0) if k == 0 else ((12, 20), 1)
        stride = ih / grid[0]
        inp = box * scale + np.array([pad[0], pad[1], pad[0], pad[1]], np.float32)
        cx, cy, w, h = cxcywh(inp)
        gx, gy = int(cx // stride), int(cy // stride)
        aw, ah = TINY_ANCHORS[TINY_MASKS[rank][0]]
        head = heads[grid]
        head[0, :6, gy, gx] = [logit(cx / stride - gx), logit(cy / stride - gy),
                               math.log(w / aw), math.log(h / ah), 6.0, 6.0]
    outputs = {f"head{i}": t.reshape(1, 3 * (5 + C), *g) for i, (g, t) in enumerate(heads.items())}
    path = const_model(tmp_path / "m.onnx", outputs, inputs={"images": [1, 3, ih, iw]})
    detector = _detector(path)
    assert detector.layout.kind == "darknet"
    assert (detector.layout.input_width, detector.layout.input_height) == (iw, ih)
    np.testing.assert_allclose(_found(detector), PERSONS, atol=1.0)




def test_two_person_classes_unset_takes_class_0_and_warns(tmp_path, caplog):
    with caplog.at_level("WARNING"):
        detector = _detector(two_class_model(tmp_path / "m.onnx"))
    assert detector.layout.persons == (0,)
    assert "0: Normal, 1: Fall" in detector.warning and "person_classes" in detector.warning
    assert detector.warning in caplog.text
    np.testing.assert_allclose(_found(detector), PERSONS[:1], atol=1.0)


@pytest.mark.parametrize("wanted", [("Normal", "fall"), (0, 1)], ids=["names", "ids"])
def test_two_person_classes_set_finds_both(tmp_path, wanted):
    detector = _detector(two_class_model(tmp_path / "m.onnx"), person_classes=wanted)
    assert detector.layout.persons == (0, 1) and detector.warning is None
    np.testing.assert_allclose(_found(detector), PERSONS, atol=1.0)


def test_unknown_person_class_names_the_classes(tmp_path):
    from monitor.errors import ConfigError

    with pytest.raises(ConfigError, match=r"no class named 'person'.*0: Normal, 1: Fall"):
        _detector(two_class_model(tmp_path / "m.onnx"), person_classes=("person",))


def test_a_threshold_below_one_in_a_thousand_is_honoured(tmp_path):
    rows = np.zeros((1, 20, 5 + C), np.float32)
    rows[0, 0] = [*cxcywh(to_input(PERSONS[0])), 0.02, 0.025, 0.0, 0.0]  # score 5e-4
    path = const_model(tmp_path / "m.onnx", {"output0": rows})
    np.testing.assert_allclose(_found(_detector(path, score_threshold=1e-4)), PERSONS[:1],
                               atol=1.0)
    assert len(_found(_detector(path, score_threshold=1e-3))) == 0


def test_darknet_threshold_below_one_in_a_thousand_is_honoured(tmp_path):
    heads = darknet_heads([10, 20], TINY_ANCHORS, TINY_MASKS)
    for head in heads.values():  # every object at score ~5e-4: sig(-3.4) * sig(-4.6)
        view = head.reshape(3, 5 + C, *head.shape[2:])
        view[:, 4] = np.where(view[:, 4] > 0, -3.4, view[:, 4])
        view[:, 5] = np.where(view[:, 5] > 0, -4.6, view[:, 5])
    path = const_model(tmp_path / "m.onnx", heads)
    np.testing.assert_allclose(_found(_detector(path, score_threshold=1e-4)), PERSONS, atol=1.0)
    assert len(_found(_detector(path, score_threshold=1e-3))) == 0


def test_pre_merge_mask_drops_raw_boxes_in_frame_pixels_before_merging(tmp_path):
    """The hook masks use: it sees raw boxes in frame pixels and its False rows are gone."""
    detector = _detector(const_model(tmp_path / "m.onnx", {"output0": rows_v5()}))
    frame = np.full((FRAME_H, FRAME_W, 3), 100, np.uint8)
    seen = []

    def left_half_masked(boxes_px: np.ndarray) -> np.ndarray:
        seen.append(boxes_px.copy())
        return boxes_px[:, 0] >= FRAME_W / 2

    result = detector.detect_timed(frame, pre_merge=left_half_masked)
    np.testing.assert_allclose(seen[0][np.argsort(seen[0][:, 0])], PERSONS, atol=1.0)
    np.testing.assert_allclose(result.persons.boxes_px, PERSONS[1:], atol=1.0)
    assert result.candidates == 1
    from monitor.errors import DetectorError

    with pytest.raises(DetectorError, match="pre-merge mask"):
        detector.detect_timed(frame, pre_merge=lambda b: np.ones(len(b) + 1, bool))
