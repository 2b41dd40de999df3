"""How far a tool calibration (``calibration.calibrate_tool``) can be trusted, from the tracker's
expected noise rather than fixed limits.

The same flange poses are replayed through the solver with tracker poses made exact from the
fitted transforms and then disturbed by noise as large as the tracker's own (``TrackerNoise``).
Over those repeats:

* the spread of the recovered mounting (X) and tracker frame (Y) says how well the pose set
  determines them: wrist turns that are too small or about too few axes leave them uncertain by
  centimetres although every residual looks small (the conditioning);
* the worst per-pose residual says what noise alone gives: residuals beyond it mean wrong pairs
  (order, units), residuals within it are only the tracker's noise.

The repeats use a fixed seed, so the same input always gets the same verdict. What it cannot
do: see a systematic tracker error (its ±10 mm accuracy, dynamic lag) that is the same on every
pose, or noise larger than the one assumed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from monitor.geometry.calibration import (
    ToolCalibration,
    calibrate_tool,
    invert_rigid,
    rotation_angle_deg,
)
from monitor.geometry.errors import GeometryError

TRIALS = 16
# the noise alone may give residuals up to this factor above the worst one seen in the repeats
# before a pose is taken for a wrong pair (24 repeats see the tail of the noise only roughly)
RESIDUAL_MARGIN = 1.5


@dataclass(frozen=True)
class TrackerNoise:
    """Expected tracker noise per axis (one standard deviation): OTUS documents ±1 mm precision
    and ±1 deg orientation precision."""

    mm: float = 1.0
    deg: float = 1.0


@dataclass(frozen=True)
class CalibrationQuality:
    """``*_error_*``: RMS error of the mounting (X) and of the tracker frame (Y) over the noisy
    repeats (inf when a repeat could not be solved); ``noise_residual_*``: the worst per-pose
    residual the noise alone gave; ``spread_deg``: the largest relative wrist turn."""

    spread_deg: float
    mount_error_mm: float
    mount_error_deg: float
    frame_error_mm: float
    frame_error_deg: float
    noise_residual_mm: float
    noise_residual_deg: float

    @property
    def residual_limit_mm(self) -> float:
        return RESIDUAL_MARGIN * self.noise_residual_mm

    @property
    def residual_limit_deg(self) -> float:
        return RESIDUAL_MARGIN * self.noise_residual_deg


def _noisy(b: np.ndarray, noise: TrackerNoise, rng: np.random.Generator) -> np.ndarray:
    out = b.copy()
    turn, _ = cv2.Rodrigues(np.radians(rng.normal(0.0, noise.deg, 3)))
    out[:3, :3] = b[:3, :3] @ turn
    out[:3, 3] += rng.normal(0.0, noise.mm, 3) / 1000.0
    return out


def assess_tool_calibration(flange_poses: list[np.ndarray] | np.ndarray, cal: ToolCalibration,
                            noise: TrackerNoise = TrackerNoise(), trials: int = TRIALS,
                            seed: int = 0) -> CalibrationQuality:
    """Replay ``flange_poses`` with tracker poses exact for ``cal`` plus ``noise``."""
    a = np.asarray(flange_poses, dtype=float).reshape(-1, 4, 4)
    x, y = cal.flange_T_tracker, cal.cell_T_reference
    exact = [invert_rigid(y) @ ai @ x for ai in a]
    rng = np.random.default_rng(seed)
    errs = np.full((trials, 4), math.inf)
    worst = np.zeros((trials, 2))
    for k in range(trials):
        try:
            c = calibrate_tool(a, [_noisy(b, noise, rng) for b in exact])
        except GeometryError:
            continue
        errs[k] = (1000 * np.linalg.norm(c.flange_T_tracker[:3, 3] - x[:3, 3]),
                   rotation_angle_deg(c.flange_T_tracker[:3, :3].T @ x[:3, :3]),
                   1000 * np.linalg.norm(c.cell_T_reference[:3, 3] - y[:3, 3]),
                   rotation_angle_deg(c.cell_T_reference[:3, :3].T @ y[:3, :3]))
        worst[k] = c.residual_mm.max(), c.residual_deg.max()
    rms = np.sqrt(np.mean(errs**2, axis=0))
    return CalibrationQuality(cal.rotation_spread_deg, *(float(v) for v in rms),
                              float(worst[:, 0].max()), float(worst[:, 1].max()))
