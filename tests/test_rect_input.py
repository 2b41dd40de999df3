"""Rectangular input: a model with a dynamic input runs a 16:9 frame at 416x288, not 416x416.

The risk it brings is a person the square would have found and the rectangle does not: a head cut
off by the top of the frame, a figure at a corner, the feet on the bottom edge, all of them now
next to the end of the tensor instead of 91 px of grey. So the same frames run through the same
synthetic model both ways and must give the same persons, and the output-shape check must hold at
every input size the rectangle makes.
"""

from __future__ import annotations

import numpy as np
import pytest

from monitor.detector import Detector, DetectorConfig, ModelLayout
from monitor.detector.preprocess import Letterboxer, fitted_input
from monitor.detector.shapes import OutputShapes
from monitor.errors import DetectorError
from monitor.scene import Figure, draw_figure, random_frames


def _layout(centered: bool = True, rect: bool = True, strides=(8, 16, 32)) -> ModelLayout:
    return ModelLayout("yolov5", "images", 416, 416, centered=centered, rect=rect,
                       strides=strides)


@pytest.mark.parametrize(("frame", "want"), [
    ((1280, 720), (416, 288)),  # 416x234 of image: two bands of 64 px dropped
    ((640, 480), (416, 352)),  # 416x312
    ((720, 1280), (288, 416)),  # portrait
    ((1000, 1000), (416, 416)),
    ((4000, 300), (416, 32)),  # a strip: 416x31 of image, 1 px of padding
])
def test_the_input_shrinks_by_whole_double_strides(frame, want):
    assert fitted_input(_layout(), *frame) == want
    assert fitted_input(_layout(rect=False), *frame) == (416, 416)


def test_top_left_layouts_drop_single_strides_and_p6_models_their_own():
    assert fitted_input(_layout(centered=False), 1280, 720) == (416, 256)
    p6 = ModelLayout("yolov5", "images", 640, 640, rect=True, strides=(8, 16, 32, 64))
    assert fitted_input(p6, 1280, 720) == (640, 384)  # 640x360 of image, bands of 128


@pytest.mark.parametrize("seed", range(4))
def test_every_frame_shape_keeps_the_image_on_the_square_grid(seed):
    # the image must sit at the same place modulo the coarsest stride as in the square, else
    # the model sees other pixels in each cell than it was measured with (envelope, self-test)
    rng = np.random.default_rng(seed)
    for _ in range(200):
        w, h = int(rng.integers(40, 4000)), int(rng.integers(40, 4000))
        for centered in (True, False):
            rect, square = Letterboxer(_layout(centered)), Letterboxer(_layout(centered, False))
            frame = np.zeros((h, w, 3), np.uint8)
            (t1, b1), (_, b2) = rect(frame), square(frame)
            iw, ih = fitted_input(rect.layout, w, h)
            assert t1.shape == (1, 3, ih, iw) and iw % 32 == 0 and ih % 32 == 0
            assert b1.scale == b2.scale
            assert (b2.pad_x - b1.pad_x) % 32 == 0 and (b2.pad_y - b1.pad_y) % 32 == 0
            assert b1.pad_x >= 0 and b1.pad_x + w * b1.scale <= iw + 0.5
            assert b1.pad_y >= 0 and b1.pad_y + h * b1.scale <= ih + 0.5


def _edge_frames() -> list[np.ndarray]:
    """Persons where a rectangle differs from the square: cut by the top, on the bottom edge,
    in the corners, small and large; plus the accuracy test's random frames."""
    frames = []
    for feet, height in (((640, 719), 900), ((60, 719), 500), ((1230, 200), 260),
                         ((640, 60), 120), ((1250, 719), 400), ((30, 330), 300)):
        img = np.full((720, 1280, 3), 118, np.uint8)
        draw_figure(img, Figure((float(feet[0]), float(feet[1])), float(height), phase=0.4))
        frames.append(img)
    frames += [img for img, _ in random_frames(6, seed=7)]
    frames += [img for img, _ in random_frames(3, seed=8, size=(640, 480))]
    return frames


def test_the_rectangle_finds_the_persons_the_square_finds(synthetic_model):
    rect = Detector(synthetic_model, DetectorConfig(threads=1))
    square = Detector(synthetic_model, DetectorConfig(threads=1, rectangular_input=False))
    assert rect.layout.rect and not square.layout.rect
    found = 0
    for img in _edge_frames():
        a, b = rect.detect(img), square.detect(img)
        assert len(a) == len(b), f"{len(a)} persons in the rectangle, {len(b)} in the square"
        order_a, order_b = np.lexsort(a.boxes_px.T[::-1]), np.lexsort(b.boxes_px.T[::-1])
        np.testing.assert_allclose(a.boxes_px[order_a], b.boxes_px[order_b], atol=0.5)
        np.testing.assert_allclose(a.scores[order_a], b.scores[order_b], atol=1e-3)
        found += len(a)
    assert found >= 10  # the frames hold persons, so "none both ways" cannot pass
    assert rect.self_test() is None and square.self_test() is None


def test_a_changed_output_at_a_rectangular_input_is_a_detector_fault(synthetic_model):
    # the shapes at 416x288 are derived from the warm-up's at 416x416: a model that gives a
    # wrong grid at a frame shape it never saw before is refused, not decoded as best it can
    det = Detector(synthetic_model, DetectorConfig(threads=1))
    load = det.output_shapes
    at = load.at_input(det.layout, ModelLayout(**{**det.layout.__dict__, "input_height": 288}))
    assert [s[2:] for s in at.shapes] == [(9, 13), (18, 26)]
    good = [np.zeros((1, 255, 9, 13), np.float32), np.zeros((1, 255, 18, 26), np.float32)]
    at.check(good, 1)
    with pytest.raises(DetectorError, match=r"output_26.*shape"):
        at.check([good[0], np.zeros((1, 255, 26, 26), np.float32)], 1)
    # a v5-style export: rows follow the grid cells (3 anchors each)
    v5 = ModelLayout("yolov5", "images", 416, 416, rect=True)
    rows = 3 * (52 * 52 + 26 * 26 + 13 * 13)
    shapes = OutputShapes("yolov5", ("output0",), ((1, rows, 85),), (frozenset(),))
    assert shapes.at_input(v5, ModelLayout("yolov5", "images", 416, 288, rect=True)).shapes == \
        ((1, 3 * (52 * 36 + 26 * 18 + 13 * 9), 85),)


def test_frames_of_two_shapes_in_one_batch_run_one_by_one(synthetic_model):
    det = Detector(synthetic_model, DetectorConfig(threads=1))
    frames = _edge_frames()
    wide, four_three = frames[0], frames[-1]
    assert wide.shape != four_three.shape
    batch = det.detect_batch([wide, four_three])
    one = [det.detect(wide), det.detect(four_three)]
    for a, b in zip(batch, one, strict=True):
        np.testing.assert_allclose(a.boxes_px, b.boxes_px, atol=0.5)
    assert sum(len(p) for p in one) >= 1
