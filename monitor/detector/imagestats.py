"""Cheap statistics of a small grey image: what the detector's image conditions are judged by
(monitor/health/conditions.py) and what its envelope is measured in
(monitor/detector/envelope.py). Pure functions of uint8 arrays; about 1 ms at 320x180."""

from __future__ import annotations

import math

import cv2
import numpy as np

# Immerkaer's noise kernel: zero on any plane or ramp, so only noise and edges pass it; for
# independent noise of sigma s its output has sigma 6 s (the root of the sum of its squares).
_NOISE_KERNEL = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
_HALF_NORMAL_MEDIAN = 0.6745  # median of |N(0, 1)|


def luminance(grey: np.ndarray) -> tuple[float, float]:
    """Mean and standard deviation of the grey levels (0..255)."""
    mean, std = cv2.meanStdDev(grey)
    return float(mean[0, 0]), float(std[0, 0])


def noise_sigma(grey: np.ndarray) -> float:
    """Sensor noise (grey levels, one sigma): Immerkaer's operator with the median of its
    magnitude instead of the mean, so edges and texture (a minority of pixels) hardly count."""
    if grey.shape[0] < 3 or grey.shape[1] < 3:
        return 0.0
    out = cv2.filter2D(grey.astype(np.float32), cv2.CV_32F, _NOISE_KERNEL)[1:-1, 1:-1]
    # every other row and column: the median of a quarter of the pixels is as good, 4x cheaper
    return float(np.median(np.abs(out[::2, ::2]))) / (6.0 * _HALF_NORMAL_MEDIAN)


def sharpness(grey: np.ndarray) -> float:
    """Variance of the Laplacian divided by the image's variance: high for sharp images and
    independent of exposure gain (a dimmer image is not a blurrier one)."""
    lap = cv2.Laplacian(grey, cv2.CV_16S)
    lap_std = float(cv2.meanStdDev(lap)[1][0, 0])
    grey_std = float(cv2.meanStdDev(grey)[1][0, 0])
    return lap_std * lap_std / (grey_std * grey_std + 1.0)


# a grey level at or above this is clipped: the sensor saturated, what stood there is gone
CLIPPED_LEVEL = 250


def saturated(grey: np.ndarray) -> float:
    """Share of the pixels that are clipped (>= ``CLIPPED_LEVEL``): glare, a sunlit patch."""
    return float(np.count_nonzero(grey >= CLIPPED_LEVEL)) / max(grey.size, 1)


def conditions(grey: np.ndarray) -> dict[str, float]:
    """The five measures: ``mean`` and ``spread`` (coefficient of variation: std / mean, so
    a dimmer image has the same spread), ``noise``, ``sharpness`` and ``saturated``."""
    mean, std = luminance(grey)
    return {"mean": mean, "spread": std / max(mean, 1.0), "noise": noise_sigma(grey),
            "sharpness": sharpness(grey), "saturated": saturated(grey)}


def finite(values: dict[str, float]) -> bool:
    return all(math.isfinite(v) for v in values.values())
