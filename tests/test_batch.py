"""Batched inference: frames of several cameras in one run give the same persons as one by one."""

from __future__ import annotations

import numpy as np
import pytest

from monitor.detector import Detector
from monitor.errors import InputError
from monitor.scene import random_frames
from monitor.types import FrameInfo
from tests.onnx_models import bright_squares, yolov8_like


def camera_frames() -> list[np.ndarray]:
    """Four cameras: two 1080p, one 720p, one 4:3; all with persons but one."""
    frames = [f for f, t in random_frames(12, seed=11, size=(1920, 1080)) if t.persons][:2]
    frames += [next(f for f, t in random_frames(8, seed=12, size=(1280, 720)) if t.persons)]
    frames += [next(random_frames(1, seed=13, size=(800, 600)))[0]]
    return frames


def test_batched_and_one_by_one_give_the_same_persons_per_frame(detector):
    assert detector.batchable
    images = camera_frames()
    infos = [FrameInfo(f"cam{i}", 7, 1.5, im.shape[1], im.shape[0])
             for i, im in enumerate(images)]
    alone = [detector.detect(im, fr) for im, fr in zip(images, infos, strict=True)]
    together = detector.detect_batch(images, infos)
    assert sum(len(p) for p in alone) >= 4
    for a, b, info in zip(alone, together, infos, strict=True):
        assert b.frame == info
        np.testing.assert_allclose(b.boxes_px, a.boxes_px, atol=1e-3)
        np.testing.assert_allclose(b.scores, a.scores, atol=1e-5)
    # twice in a row: the reused canvases of each batch slot hold no stale pixels
    again = detector.detect_batch(images[::-1], infos[::-1])
    for a, b in zip(alone[::-1], again, strict=True):
        np.testing.assert_allclose(b.boxes_px, a.boxes_px, atol=1e-3)


def test_a_model_with_a_fixed_batch_of_one_runs_frames_in_turn(tmp_path):
    det = Detector(yolov8_like(tmp_path / "v8.onnx"))
    assert not det.batchable
    images = bright_squares(3, seed=4)
    together = det.detect_batch(images)
    alone = [det.detect(im) for im in images]
    assert [len(p) for p in together] == [len(p) for p in alone] and sum(map(len, alone)) >= 3
    for a, b in zip(alone, together, strict=True):
        np.testing.assert_allclose(b.boxes_px, a.boxes_px, atol=1e-3)


def test_bad_batch_input_is_one_line(detector):
    with pytest.raises(InputError, match="2 images but 1 frame infos"):
        detector.detect_batch([np.zeros((8, 8, 3), np.uint8)] * 2, [None])
    with pytest.raises(InputError, match="not a BGR image"):
        detector.detect_batch([np.zeros((8, 8, 3), np.uint8), np.zeros((8, 8), np.uint8)])
