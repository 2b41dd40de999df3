"""Synthetic flange / tracker pose pairs for the tool calibration (AX = XB) tests, with the seed
report's mounting and noise."""

from __future__ import annotations

import math

import numpy as np

from monitor import geometry as geo

# the seed report's mounting: [13.55, 1.82, 49.17] mm, about 180 deg about z
MOUNT = geo.rigid(geo.rpy_to_matrix(0.4, -0.6, 179.5), np.array([13.55, 1.82, 49.17]) / 1000)


REFERENCE = geo.rigid(geo.rpy_to_matrix(2.0, -1.0, 35.0), [1.2, -0.8, 0.05])


def random_rotation(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = math.radians(rng.uniform(-max_deg, max_deg))
    import cv2

    r, _ = cv2.Rodrigues(axis * angle)
    return r


def pose_pairs(rng: np.random.Generator, n: int, noise_mm: float, noise_deg: float,
               spread_deg: float = 120.0):
    """Flange poses in the cell (the wrist turned up to ``spread_deg`` about random axes) and
    the poses the tracker reports for them, with uniform noise of ±noise_mm per axis and a turn
    of up to ±noise_deg about a random axis."""
    flange, tracker = [], []
    for _ in range(n):
        a = geo.rigid(random_rotation(rng, spread_deg) @ geo.rpy_to_matrix(180, 0, 0),
                      rng.uniform([0.3, -0.5, 0.4], [0.9, 0.5, 1.2]))
        b = np.linalg.inv(REFERENCE) @ a @ MOUNT  # exact: Y B = A X
        noisy = b.copy()
        noisy[:3, :3] = b[:3, :3] @ random_rotation(rng, noise_deg)
        noisy[:3, 3] += rng.uniform(-noise_mm, noise_mm, 3) / 1000
        flange.append(a)
        tracker.append(noisy)
    return flange, tracker
