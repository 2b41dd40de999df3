"""The analysis image: the one small copy of a frame that a camera's image checks look at
(issue 49). The camera checks (blinded, envelope, frozen, defocused, moved), the watch zones and
the objects-since-commissioning watch all judge this copy, made once a frame, and the
reference image the same way once, so a frame and its reference are always compared in the
same pixels.

It is made by ``INTER_LINEAR``: at 1920 -> 320 each output pixel is the mean of 2x2 input
pixels, as the detector's own letterbox (``INTER_LINEAR`` to its input size) takes them, so the
envelope's noise, sharpness and luminance limits (measured in this image: conditions.py) judge
what the detector sees. ``INTER_AREA`` (the mean of all 6x6) would read every pixel (2 ms a
1080p frame against 0.35) and average away six times the noise and much of a blur, which the
envelope check must see."""

from __future__ import annotations

import cv2
import numpy as np


def analysis_size(width: int, height: int, analysis_width: int) -> tuple[int, int]:
    """(width, height) of the analysis image of a ``width`` x ``height`` frame: at most
    ``analysis_width`` wide (never wider than the frame), the frame's aspect ratio."""
    sw = min(analysis_width, width)
    return sw, max(16, round(sw * height / width))


def analysis_bgr(frame_bgr: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The frame's analysis image (BGR uint8) at ``size`` (module docstring)."""
    return cv2.resize(frame_bgr, size, interpolation=cv2.INTER_LINEAR)
