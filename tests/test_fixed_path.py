"""The work around inference made cheaper (issue 49) gives the same answers as the plain way.

Each test compares a stage's faster code with a direct, obviously correct computation of the
same thing, on frames and layouts that take every branch (padding left/right or top/bottom,
RGB and BGR, NCHW and NHWC, a reused canvas after a change of frame size)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from monitor.detector import Letterboxer, ModelLayout


def _plain_letterbox(image: np.ndarray, layout: ModelLayout) -> np.ndarray:
    """Resize into a fresh padded canvas, reorder the channels, scale: one frame, no reuse."""
    h, w = image.shape[:2]
    box = Letterboxer(layout)(image)[1]
    nw, nh = max(1, round(w * box.scale)), max(1, round(h * box.scale))
    px, py = int(box.pad_x), int(box.pad_y)
    canvas = np.full((box.input_height, box.input_width, 3), layout.pad_value, np.uint8)
    cv2.resize(image, (nw, nh), dst=canvas[py:py + nh, px:px + nw],
               interpolation=cv2.INTER_LINEAR)
    rgb = canvas[..., ::-1] if layout.rgb else canvas
    tensor = rgb.astype(np.float64) * layout.scale
    if not layout.input_nhwc:
        tensor = tensor.transpose(2, 0, 1)
    return tensor[None].astype(np.float32)


@pytest.mark.parametrize("layout", [
    ModelLayout("darknet", "x", 416, 416),
    ModelLayout("darknet", "x", 416, 416, rect=True),
    ModelLayout("yolox", "x", 416, 416, rgb=False, scale=1.0, centered=False),
    ModelLayout("yolov5", "x", 320, 320, input_nhwc=True),
], ids=["square", "rectangular", "bgr-top-left", "nhwc"])
def test_letterbox_tensor_is_the_plain_resize_reorder_and_scale(layout):
    rng = np.random.default_rng(7)
    letterboxer = Letterboxer(layout)  # one instance: its canvas and planes are reused
    for shape in [(1080, 1920), (1080, 1920), (720, 1280), (1920, 1080), (301, 199), (1, 1)]:
        image = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
        tensor, _ = letterboxer(image)
        expected = _plain_letterbox(image, layout)
        assert tensor.shape == expected.shape
        np.testing.assert_allclose(tensor, expected, rtol=0, atol=1e-6)
