"""The visible fraction the detector needs, measured beside the operating envelope
(monitor/detector/visible.py, docs/occlusion.md "The visible fraction, measured")."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from monitor.detector import Detector, DetectorConfig, visible
from monitor.detector.selftest import builtin_case
from monitor.errors import ModelError
from monitor.types import FrameInfo, Persons


def test_the_synthetic_model_needs_a_fifth_from_below_and_two_fifths_from_the_side(
        synthetic_model, tmp_path):
    model = tmp_path / "m.onnx"
    shutil.copy(synthetic_model, model)
    detector = Detector(model, DetectorConfig(threads=1))
    got = visible.for_detector(detector, 0.9)
    assert got is not None
    assert 0.1 < got.from_below <= 0.4 and 0.25 < got.from_side <= 0.6, got.table()
    assert got.needed == max(got.from_below, got.from_side)
    # stored beside the model and read back (not measured again)
    path = visible.sidecar_path(model)
    assert path.is_file()
    again = visible.for_detector(detector, 0.9)
    assert again == got
    # another minimum recall measures anew
    assert visible.for_detector(detector, 1.0, store=False).min_recall == 1.0


def test_a_model_that_needs_the_whole_figure_says_so():
    case = builtin_case()
    whole = np.asarray(case.box_px, np.float32)

    def detect(image: np.ndarray) -> Persons:
        # finds the person only while no fixture colour is on it
        x1, y1, x2, y2 = np.round(whole).astype(int)
        covered = (image[y1:y2, x1:x2] == visible.FIXTURE_BGR).all(axis=2).any()
        boxes = np.zeros((0, 4), np.float32) if covered else whole[None]
        return Persons(boxes, np.ones(len(boxes), np.float32),
                       FrameInfo("t", 0, 0.0, image.shape[1], image.shape[0]))

    got = visible.measure(detect, case, 8.0, 0.9)
    assert got.from_below == 1.0 and got.from_side == 1.0


def test_a_model_that_misses_the_whole_figure_is_a_model_error():
    def detect(image: np.ndarray) -> Persons:
        return Persons(np.zeros((0, 4), np.float32), np.zeros(0, np.float32),
                       FrameInfo("t", 0, 0.0, image.shape[1], image.shape[0]))

    with pytest.raises(ModelError, match="no visible fraction"):
        visible.measure(detect, builtin_case(), 8.0, 0.9)


def test_a_broken_sidecar_is_one_line_naming_the_file():
    with pytest.raises(ModelError, match=r"x\.json: not a measured visible fraction"):
        visible.from_json("{}", "x.json")
