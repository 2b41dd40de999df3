"""``monitor zones calibrate-tool``: read pose pairs, solve A X = Y B, judge the result against the
tracker's expected noise (monitor/geometry/calibration_quality.py), write the zone file."""

from __future__ import annotations

import argparse
import csv
import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from monitor import geometry as geo
from monitor.errors import ConfigError, InputError
from monitor.geometry.calibration_quality import (
    CalibrationQuality,
    TrackerNoise,
    assess_tool_calibration,
)

POSE_COLUMNS = [f"{who} {axis}" for who in ("flange", "tracker")
                for axis in ("x", "y", "z", "qx", "qy", "qz", "qw")]
# under this the wrist turns say little about the rotation axes (shown in the refusal)
GOOD_SPREAD_DEG = 30.0


def positive_number(text: str) -> float:
    """argparse type: a finite number above 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number above 0, got {text!r}")
    return value


def read_pose_pairs(path: Path) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Flange and tracker poses from a CSV of 14 numbers a row; one-line InputError naming the
    row (and the column of a non-finite number) otherwise."""
    flange, tracker = [], []
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            for n, row in enumerate(csv.reader(fh)):
                cells = [c.strip() for c in row if c.strip()]
                if not cells or cells[0].startswith("#"):
                    continue
                try:
                    v = [float(c) for c in cells]
                except ValueError:
                    if n == 0:
                        continue  # header line
                    raise InputError(f"{path}:{n + 1}: not numbers: {row}") from None
                if len(v) != 14:
                    raise InputError(f"{path}:{n + 1}: a row needs 14 numbers (flange "
                                     "x,y,z,qx,qy,qz,qw, tracker x,y,z,qx,qy,qz,qw), got "
                                     f"{len(v)}")
                bad = next((j for j, x in enumerate(v) if not math.isfinite(x)), None)
                if bad is not None:
                    raise InputError(f"{path}:{n + 1}: column {bad + 1} ({POSE_COLUMNS[bad]}) "
                                     f"is {cells[bad]!r}, not a finite number")
                try:
                    flange.append(geo.rigid(geo.quaternion_to_matrix(v[3:7]), v[0:3]))
                    tracker.append(geo.rigid(geo.quaternion_to_matrix(v[10:14]), v[7:10]))
                except geo.GeometryError as exc:
                    raise InputError(f"{path}:{n + 1}: {exc}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc}") from None
    return flange, tracker


def conditioning_fault(q: CalibrationQuality, noise: TrackerNoise, max_mm: float,
                       max_deg: float) -> str | None:
    """One line when the pose set leaves X or Y more uncertain than the limits."""
    worst_mm = max(q.mount_error_mm, q.frame_error_mm)
    worst_deg = max(q.mount_error_deg, q.frame_error_deg)
    if worst_mm <= max_mm and worst_deg <= max_deg:
        return None
    advice = (f"turn the flange by {GOOD_SPREAD_DEG:.0f} deg or more about different axes"
              if q.spread_deg < 2 * GOOD_SPREAD_DEG else "use more poses, turning the flange "
              "about different axes")
    return (f"calibrate-tool: the poses cannot determine the transforms: wrist turns span "
            f"{q.spread_deg:.0f} deg; with tracker noise of {noise.mm:g} mm / {noise.deg:g} deg "
            f"the mounting is uncertain by {_err(q.mount_error_mm)} mm / "
            f"{_err(q.mount_error_deg)} deg and the tracker frame by {_err(q.frame_error_mm)} "
            f"mm / {_err(q.frame_error_deg)} deg (limits --max-error-mm {max_mm:g}, "
            f"--max-error-deg {max_deg:g}): nothing written ({advice})")


def _err(v: float) -> str:
    return "unbounded" if not math.isfinite(v) else f"{v:.1f}"


def calibrate_tool(args: argparse.Namespace, read: Callable[[Path], dict],
                   write: Callable[[dict, Path], object]) -> int:
    data = read(args.file)
    if not isinstance(data.get("tool"), dict):
        raise ConfigError(f"{args.file}: no 'tool:' section to calibrate (add the tool's shape "
                          "first, zones/README.md)")
    flange, tracker = read_pose_pairs(args.csv)
    try:
        cal = geo.calibrate_tool(flange, tracker)
    except geo.GeometryError as exc:
        raise ConfigError(f"calibrate-tool: {exc}") from None
    noise = TrackerNoise(args.tracker_noise_mm, args.tracker_noise_deg)
    quality = assess_tool_calibration(flange, cal, noise)
    print(f"{'pose':>4}  {'residual_mm':>11}  {'residual_deg':>12}")
    for n, (mm, deg) in enumerate(zip(cal.residual_mm, cal.residual_deg, strict=True)):
        print(f"{n + 1:>4}  {mm:>11.2f}  {deg:>12.2f}")
    print(f"RMS {float(np.sqrt(np.mean(cal.residual_mm ** 2))):.2f} mm, "
          f"{float(np.sqrt(np.mean(cal.residual_deg ** 2))):.2f} deg over {len(flange)} poses; "
          f"largest relative rotation {cal.rotation_spread_deg:.0f} deg")
    print(f"with tracker noise {noise.mm:g} mm / {noise.deg:g} deg per axis: mounting "
          f"±{_err(quality.mount_error_mm)} mm / ±{_err(quality.mount_error_deg)} deg, "
          f"tracker frame ±{_err(quality.frame_error_mm)} mm / "
          f"±{_err(quality.frame_error_deg)} deg (RMS); the noise alone gives residuals up to "
          f"{quality.noise_residual_mm:.1f} mm / {quality.noise_residual_deg:.1f} deg")
    x, y = cal.flange_T_tracker, cal.cell_T_reference
    offset = {"translation_mm": [round(float(v) * 1000, 3) for v in x[:3, 3]],
              "rpy_deg": [round(v, 4) for v in geo.matrix_to_rpy_deg(x[:3, :3])],
              "given_as": "tracker_in_tool"}
    frame = {"translation_m": [round(float(v), 5) for v in y[:3, 3]],
             "rpy_deg": [round(v, 4) for v in geo.matrix_to_rpy_deg(y[:3, :3])]}
    print(f"tool.offset: {offset}")
    print(f"tracker_frame: {frame}")
    if len(flange) < 10:
        print(f"monitor: warning: only {len(flange)} poses: the residuals say little; use 20 "
              "or more, turning the flange about different axes", file=sys.stderr)
    fault = conditioning_fault(quality, noise, args.max_error_mm, args.max_error_deg)
    if fault:
        raise ConfigError(fault)
    limit_mm = args.max_residual_mm or quality.residual_limit_mm
    limit_deg = args.max_residual_deg or quality.residual_limit_deg
    worst_mm, worst_deg = float(cal.residual_mm.max()), float(cal.residual_deg.max())
    if worst_mm > limit_mm or worst_deg > limit_deg:
        raise ConfigError(f"calibrate-tool: residual {worst_mm:.1f} mm / {worst_deg:.1f} deg "
                          f"exceeds {limit_mm:.1f} mm / {limit_deg:.1f} deg (more than tracker "
                          f"noise of {noise.mm:g} mm / {noise.deg:g} deg explains; "
                          "--max-residual-mm / --max-residual-deg set it): nothing written "
                          "(check the pose pairs: same order? same units?)")
    if worst_mm > 5.0 or worst_deg > 3.0:
        print(f"monitor: warning: residuals up to {worst_mm:.1f} mm / {worst_deg:.1f} deg are "
              f"within what tracker noise of {noise.mm:g} mm / {noise.deg:g} deg gives; the "
              f"tracker frame is known to ±{quality.frame_error_mm:.1f} mm", file=sys.stderr)
    if args.dry_run:
        return 0
    data["tool"]["offset"] = offset
    data["tracker_frame"] = frame
    write(data, args.file)
    print(f"calibrated the tool of {args.file}")
    return 0
