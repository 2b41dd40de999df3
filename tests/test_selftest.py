"""Detector sanity: broken models are faults (never "no persons") and the self-test sees them."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from monitor.config import load_config
from monitor.detector import TINY_ANCHORS, TINY_MASKS, Detector, DetectorConfig
from monitor.detector.selftest import builtin_case
from monitor.errors import ConfigError, DetectorError
from tests.onnx_models import darknet_heads


def broken_synthetic(src: Path, dst: Path, layer: str, value: float) -> Path:
    """The synthetic model with one layer's weights set to ``value`` (0: blind, NaN: corrupt)."""
    model = onnx.load(str(src))
    for init in model.graph.initializer:
        if init.name == f"{layer}.weight":
            weights = numpy_helper.to_array(init).copy()
            weights[:] = value
            init.CopyFrom(numpy_helper.from_array(weights, init.name))
    onnx.save(model, str(dst))
    return dst


def nan_when_bright_model(path: Path) -> Path:
    """Darknet heads of two known persons, + 0 * sqrt(0.9 - brightest input): finite on the
    grey warm-up frame, NaN on a white frame (a model that breaks only on some inputs)."""
    heads = darknet_heads([10, 20], TINY_ANCHORS, TINY_MASKS)
    nodes = [helper.make_node("ReduceMax", ["images"], ["max"], keepdims=0),
             helper.make_node("Sub", ["limit", "max"], ["room"]),
             helper.make_node("Sqrt", ["room"], ["root"]),
             helper.make_node("Mul", ["root", "zero"], ["term"])]
    inits = [numpy_helper.from_array(np.array(0.9, np.float32), "limit"),
             numpy_helper.from_array(np.array(0.0, np.float32), "zero")]
    outs = []
    for name, value in heads.items():
        inits.append(numpy_helper.from_array(value, f"{name}_c"))
        nodes.append(helper.make_node("Add", [f"{name}_c", "term"], [name]))
        outs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, list(value.shape)))
    graph = helper.make_graph(
        nodes, "nan", [helper.make_tensor_value_info("images", TensorProto.FLOAT,
                                                     [1, 3, 320, 320])], outs, inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return path


def test_nan_outputs_raise_detector_error_not_no_persons(tmp_path):
    detector = Detector(nan_when_bright_model(tmp_path / "m.onnx"),
                        DetectorConfig(input_size=320))
    assert len(detector.detect(np.full((480, 640, 3), 100, np.uint8))) == 2
    with pytest.raises(DetectorError, match=r"NaN or infinite values"):
        detector.detect(np.full((480, 640, 3), 255, np.uint8))


def test_infinite_box_is_a_detector_error_not_a_full_frame_box(tmp_path):
    from tests.onnx_models import const_model

    heads = darknet_heads([10, 20], TINY_ANCHORS, TINY_MASKS)
    head = next(iter(heads.values())).reshape(3, 8, 10, 10)
    slot, gy, gx = (int(v[0]) for v in np.nonzero(head[:, 4] > 0))
    head[slot, 2, gy, gx] = 200.0  # finite logit, exp() overflows to an infinite width
    with pytest.raises(DetectorError, match="infinite size"):
        Detector(const_model(tmp_path / "m.onnx", heads), DetectorConfig(input_size=320))


def test_synthetic_model_with_a_nan_layer_is_refused(tmp_path, synthetic_model):
    path = broken_synthetic(synthetic_model, tmp_path / "nan.onnx", "conv22", float("nan"))
    with pytest.raises(DetectorError, match="NaN"):
        Detector(path)


def test_healthy_synthetic_model_passes_its_built_in_self_test(detector):
    assert detector.self_test_case is not None and detector.self_test_case.source == "built-in"
    assert detector.self_test() is None


@pytest.mark.parametrize("size", [256, 320])
def test_built_in_self_test_at_smaller_input_sizes(tmp_path, size):
    from monitor.models import synthetic

    synthetic.write_model(tmp_path / "m.onnx", input_size=size)
    assert Detector(tmp_path / "m.onnx").self_test() is None


def test_self_test_leaves_the_frame_buffer_alone(detector):
    """A self-test between two frames (or from another thread) must not change what the next
    detect sees: it uses its own input buffer."""
    frame = np.full((720, 1280, 3), 120, np.uint8)
    tensor_before, _ = detector._letterbox(frame)
    kept = tensor_before.copy()
    assert detector.self_test() is None
    np.testing.assert_array_equal(detector._letterbox._tensor, kept)


def test_blind_synthetic_model_fails_the_self_test(tmp_path, synthetic_model):
    detector = Detector(broken_synthetic(synthetic_model, tmp_path / "blind.onnx", "conv0", 0.0))
    fault = detector.self_test()
    assert fault is not None
    assert (fault.name, fault.stop, fault.source) == ("detector_self_test", True, "detector")
    assert "no person" in fault.reason


def test_wrong_preprocessing_fails_the_self_test(tmp_path, synthetic_model):
    """Pixels divided by 255 twice (a classic export mistake): the test sees it."""
    import dataclasses

    detector = Detector(synthetic_model)
    detector.layout = dataclasses.replace(detector.layout, scale=1 / 255 / 255)
    fault = detector.self_test()
    assert fault is not None and fault.name == "detector_self_test"


@pytest.fixture()
def self_test_image(tmp_path) -> tuple[Path, tuple[float, float, float, float]]:
    case = builtin_case()
    path = tmp_path / "known-person.png"
    cv2.imwrite(str(path), case.image)
    return path, case.box_px


def test_all_zero_outputs_fail_a_user_self_test(tmp_path, self_test_image):
    from tests.onnx_models import const_model

    heads = {f"head{i}": np.zeros((1, 24, g, g), np.float32) for i, g in enumerate((10, 20))}
    image, box = self_test_image
    detector = Detector(const_model(tmp_path / "zero.onnx", heads),
                        DetectorConfig(input_size=320, self_test_image=str(image),
                                       self_test_box=box))
    fault = detector.self_test()
    assert fault is not None and fault.name == "detector_self_test"
    assert "known-person.png" in fault.reason


def test_user_self_test_with_the_synthetic_model(synthetic_model, self_test_image):
    image, box = self_test_image
    good = Detector(synthetic_model, DetectorConfig(self_test_image=str(image),
                                                    self_test_box=box))
    assert good.self_test_case.source == str(image) and good.self_test() is None
    elsewhere = (0.0, 0.0, 60.0, 120.0)  # the box names a place where nobody stands
    bad = Detector(synthetic_model, DetectorConfig(self_test_image=str(image),
                                                   self_test_box=elsewhere))
    assert bad.self_test().name == "detector_self_test"


def test_self_test_settings_in_monitor_toml(tmp_path, self_test_image):
    image, box = self_test_image
    (tmp_path / "monitor.toml").write_text(
        f"[detector]\nself_test_image = \"{image.name}\"\n"
        f"self_test_box = [{', '.join(str(v) for v in box)}]\nself_test_period_s = 0\n"
        f"person_classes = [\"person\", 3]\n")
    cfg = load_config(tmp_path / "monitor.toml").detector
    assert Path(cfg.self_test_image) == image  # relative to the config file
    assert cfg.self_test_box == box and cfg.self_test_period_s == 0
    assert cfg.person_classes == ("person", 3)


@pytest.mark.parametrize(("values", "message"), [
    ({"self_test_image": "x.png"}, "go together"),
    ({"self_test_period_s": -1.0}, "self_test_period_s"),
    ({"self_test_period_s": float("nan")}, "self_test_period_s"),
    ({"self_test_image": "x.png", "self_test_box": (10.0, 10.0, 5.0, 20.0)}, "x1 < x2"),
    ({"person_classes": ()}, "person_classes: empty"),
    ({"score_threshold": float("nan")}, "score_threshold"),
])
def test_bad_detector_settings_are_refused(values, message):
    with pytest.raises(ConfigError, match=message):
        DetectorConfig(**values)


def test_unreadable_self_test_image_is_refused_at_start(tmp_path, synthetic_model):
    with pytest.raises(ConfigError, match="cannot read"):
        Detector(synthetic_model, DetectorConfig(self_test_image=str(tmp_path / "none.png"),
                                                 self_test_box=(1.0, 1.0, 9.0, 9.0)))


def test_nan_outputs_stop_the_pipeline_with_detector_error(tmp_path):
    """End to end: a model that turns NaN mid-run is a STOP with its reason, never RUN."""
    from monitor.pipeline import Pipeline
    from monitor.policy import PolicyConfig
    from monitor.types import FrameInfo

    detector = Detector(nan_when_bright_model(tmp_path / "m.onnx"),
                        DetectorConfig(input_size=320))
    pipeline = Pipeline(detector, "cam0", PolicyConfig(clear_time=0.2, restart_interlock="auto"))
    white = np.full((480, 640, 3), 255, np.uint8)
    for i in range(5):
        result = pipeline.process(white, FrameInfo("cam0", i, i * 0.1, 640, 480), i * 0.1)
        assert result.command.state == "STOP"
    reasons = {r.code: r.message for r in result.command.reasons}
    assert "NaN or infinite" in reasons["detector_error"]
