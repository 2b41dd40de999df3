"""Fitting frames into the model input (letterbox), without allocating per frame."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from monitor.detector.layouts import ModelLayout


@dataclass(frozen=True)
class Letterbox:
    """How a frame was fitted into the model input: input = frame * scale + (pad_x, pad_y),
    in an input of ``input_width`` x ``input_height`` pixels."""

    scale: float
    pad_x: float
    pad_y: float
    input_width: int = 0
    input_height: int = 0

    def to_frame(self, boxes: np.ndarray) -> np.ndarray:
        out = boxes.astype(np.float32, copy=True)
        out[:, [0, 2]] = (out[:, [0, 2]] - self.pad_x) / self.scale
        out[:, [1, 3]] = (out[:, [1, 3]] - self.pad_y) / self.scale
        return out


def fitted_input(layout: ModelLayout, frame_width: int, frame_height: int) -> tuple[int, int]:
    """The input size (width, height) a frame of this size runs at.

    A model with a fixed input runs at it. A model with a dynamic input (``layout.rect``)
    keeps the scale of the full input but gives up whole bands of padding: YOLOv5's
    rectangular inference, a 1280x720 frame at 416 runs at 416x288 (about 30 % fewer
    operations). Each side shrinks by whole steps of two coarsest strides when the image is
    centred (one when it sits top-left), so the image keeps its place on every output grid and
    the model sees the same pixels in the same cells as in the full square.
    """
    iw, ih = layout.input_width, layout.input_height
    if not layout.rect:
        return iw, ih
    scale = min(iw / frame_width, ih / frame_height)
    nw, nh = max(1, round(frame_width * scale)), max(1, round(frame_height * scale))
    step = max(32, *layout.strides) * (2 if layout.centered else 1)
    return iw - step * ((iw - nw) // step), ih - step * ((ih - nh) // step)


class Letterboxer:
    """Fits frames into the model input keeping the aspect ratio, reusing one uint8 canvas.

    The padding is painted only when the frame geometry changes, and only the image region of
    the float tensor is converted, so a call costs one resize and one conversion of the visible
    pixels. The returned tensor is reused by the next call.
    """

    def __init__(self, layout: ModelLayout) -> None:
        self.layout = layout
        self._canvas = np.empty((0, 0, 3), np.uint8)
        self._tensor = np.empty((1, 3, 0, 0), np.float32)
        self._geometry: tuple[int, ...] | None = None
        self._planes: tuple[np.ndarray, ...] | None = None  # the split channels, reused

    def __call__(self, image_bgr: np.ndarray) -> tuple[np.ndarray, Letterbox]:
        """Returns (NCHW or NHWC float32 tensor, the letterbox)."""
        layout = self.layout
        h, w = image_bgr.shape[:2]
        # the scale always comes from the full input: a rectangular input only drops padding
        scale = min(layout.input_width / w, layout.input_height / h)
        iw, ih = fitted_input(layout, w, h)
        nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
        px, py = ((iw - nw) // 2, (ih - nh) // 2) if layout.centered else (0, 0)
        if self._geometry != (nw, nh, px, py, iw, ih):
            if self._canvas.shape[:2] != (ih, iw):
                self._canvas = np.empty((ih, iw, 3), np.uint8)
                self._tensor = np.empty((1, 3, ih, iw), np.float32)
            self._canvas[:] = layout.pad_value
            self._tensor[:] = np.float32(layout.pad_value * layout.scale)
            self._geometry = (nw, nh, px, py, iw, ih)
            self._planes = tuple(np.empty((nh, nw), np.uint8) for _ in range(3))
        canvas = self._canvas
        view = canvas[py:py + nh, px:px + nw]
        cv2.resize(image_bgr, (nw, nh), dst=view, interpolation=cv2.INTER_LINEAR)
        box = Letterbox(scale, float(px), float(py), iw, ih)
        if layout.input_nhwc:
            rgb = cv2.cvtColor(canvas, cv2.COLOR_BGR2RGB) if layout.rgb else canvas
            return (rgb.astype(np.float32) * np.float32(layout.scale))[None], box
        # HWC -> CHW: split into contiguous planes first (one pass in OpenCV), then scale each
        # into its tensor plane; a strided multiply over the interleaved view reads every
        # channel's bytes three times apart and costs about twice as much
        planes = cv2.split(view, self._planes)
        order = (2, 1, 0) if layout.rgb else (0, 1, 2)
        scale = np.float32(layout.scale)
        for k, c in enumerate(order):
            np.multiply(planes[c], scale, out=self._tensor[0, k, py:py + nh, px:px + nw],
                        casting="unsafe")
        return self._tensor, box


def letterbox(image_bgr: np.ndarray, layout: ModelLayout) -> tuple[np.ndarray, Letterbox]:
    """One-off letterbox (see :class:`Letterboxer`)."""
    return Letterboxer(layout)(image_bgr)
