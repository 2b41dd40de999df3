"""Fitting frames into the model input (letterbox), without allocating per frame."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from monitor.detector.layouts import ModelLayout


@dataclass(frozen=True)
class Letterbox:
    """How a frame was fitted into the model input: input = frame * scale + (pad_x, pad_y)."""

    scale: float
    pad_x: float
    pad_y: float

    def to_frame(self, boxes: np.ndarray) -> np.ndarray:
        out = boxes.astype(np.float32, copy=True)
        out[:, [0, 2]] = (out[:, [0, 2]] - self.pad_x) / self.scale
        out[:, [1, 3]] = (out[:, [1, 3]] - self.pad_y) / self.scale
        return out


class Letterboxer:
    """Fits frames into the model input keeping the aspect ratio, reusing one uint8 canvas.

    The padding is painted only when the frame geometry changes, and only the image region of
    the float tensor is converted, so a call costs one resize and one conversion of the visible
    pixels. The returned tensor is reused by the next call.
    """

    def __init__(self, layout: ModelLayout) -> None:
        self.layout = layout
        self._canvas = np.full((layout.input_height, layout.input_width, 3), layout.pad_value,
                               np.uint8)
        self._geometry: tuple[int, int, int, int] | None = None
        self._tensor = np.empty((1, 3, layout.input_height, layout.input_width), np.float32)

    def __call__(self, image_bgr: np.ndarray) -> tuple[np.ndarray, Letterbox]:
        """Returns (NCHW or NHWC float32 tensor, the letterbox)."""
        layout = self.layout
        h, w = image_bgr.shape[:2]
        iw, ih = layout.input_width, layout.input_height
        scale = min(iw / w, ih / h)
        nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
        px, py = ((iw - nw) // 2, (ih - nh) // 2) if layout.centered else (0, 0)
        if self._geometry != (nw, nh, px, py):
            self._canvas[:] = layout.pad_value
            self._tensor[:] = np.float32(layout.pad_value * layout.scale)
            self._geometry = (nw, nh, px, py)
        canvas = self._canvas
        view = canvas[py:py + nh, px:px + nw]
        cv2.resize(image_bgr, (nw, nh), dst=view, interpolation=cv2.INTER_LINEAR)
        box = Letterbox(scale, float(px), float(py))
        if layout.input_nhwc:
            rgb = cv2.cvtColor(canvas, cv2.COLOR_BGR2RGB) if layout.rgb else canvas
            return (rgb.astype(np.float32) * np.float32(layout.scale))[None], box
        planes = view.transpose(2, 0, 1)  # HWC -> CHW view, BGR
        np.multiply(planes[::-1] if layout.rgb else planes, np.float32(layout.scale),
                    out=self._tensor[0, :, py:py + nh, px:px + nw], casting="unsafe")
        return self._tensor, box


def letterbox(image_bgr: np.ndarray, layout: ModelLayout) -> tuple[np.ndarray, Letterbox]:
    """One-off letterbox (see :class:`Letterboxer`)."""
    return Letterboxer(layout)(image_bgr)
