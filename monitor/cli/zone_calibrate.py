"""``monitor zones calibrate``: calibrate a camera of a zone file from image-to-cell point pairs.

A floor homography (default) or, with ``--pnp``, the extrinsics of a camera whose intrinsics
are known. Prints the reprojection error of every pair and warns when it (or too few pairs)
cannot show a wrong pair. The tracked tool's calibration is ``monitor.cli.tool_calibration``.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from monitor import geometry as geo
from monitor import zones as zn
from monitor.cli.zone_files import camera_for, numbers, read_zone_data, write_zone_data
from monitor.errors import ConfigError, InputError


def register(sub: argparse._SubParsersAction) -> None:
    """Adds ``calibrate`` to the ``monitor zones`` subcommands."""
    p = sub.add_parser("calibrate", help="calibrate a camera from image-to-cell point pairs",
                       description="Fit a floor homography (default) or, with --pnp, the "
                       "extrinsics of a camera whose intrinsics are known. Pairs are "
                       "'u,v,x,y' (floor, z = 0) or 'u,v,x,y,z' (--pnp): pixels then metres.")
    p.add_argument("file", type=Path)
    p.add_argument("--camera", help="camera id (default: the file's only camera; required "
                   "when it has several)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--pairs", help="'u,v,x,y u,v,x,y ...'")
    src.add_argument("--csv", type=Path, help="CSV file with columns u,v,x,y[,z] (header "
                     "optional)")
    p.add_argument("--pnp", action="store_true", help="solve extrinsics with the camera's K "
                   "(keeps K and distortion) instead of a homography")
    p.add_argument("--dry-run", action="store_true", help="print the errors, write nothing")
    p.set_defaults(func=cmd_calibrate)


def _read_pairs(args: argparse.Namespace) -> np.ndarray:
    rows: list[list[float]] = []
    if args.pairs:
        for token in args.pairs.replace(";", " ").split():
            rows.append(numbers(token, None, "--pairs"))
    else:
        try:
            with args.csv.open(newline="", encoding="utf-8") as fh:
                for n, row in enumerate(csv.reader(fh)):
                    cells = [c.strip() for c in row if c.strip()]
                    if not cells or cells[0].startswith("#"):
                        continue
                    try:
                        rows.append([float(c) for c in cells])
                    except ValueError:
                        if n == 0:
                            continue  # header line
                        raise InputError(f"{args.csv}:{n + 1}: not numbers: {row}") from None
        except OSError as exc:
            raise InputError(f"{args.csv}: cannot read: {exc}") from None
    if not rows:
        raise ConfigError("calibrate: no point pairs given")
    lengths = {len(r) for r in rows}
    if len(lengths) != 1 or lengths.pop() not in (4, 5):
        raise ConfigError("calibrate: each pair needs u,v,x,y or u,v,x,y,z")
    return np.array(rows, dtype=float)


RMS_WARN_PX = 2.0  # more: a wrong pair or unmodelled distortion (zones/README.md)


def cmd_calibrate(args: argparse.Namespace) -> int:
    data = read_zone_data(args.file)
    cams = data.get("cameras") or []
    args.camera = camera_for(data, args)
    cam = next(c for c in cams if c.get("id") == args.camera)
    pairs = _read_pairs(args)
    old = cam.get("calibration") or {}
    k = old.get("camera_matrix")
    dist = list(old.get("distortion") or [])
    if args.pnp:
        cal, errors = _solve_pnp(pairs, k, dist, args)
    else:
        if pairs.shape[1] == 5 and np.any(pairs[:, 4] != 0):
            raise ConfigError("calibrate: a floor homography needs floor points (z = 0); use "
                              "--pnp for points above the floor")
        if len(pairs) < 4:
            raise ConfigError(f"calibrate: needs at least 4 point pairs, got {len(pairs)}")
        cal = {"type": "homography", "pairs": pairs[:, :4].tolist()}
        if k is not None:
            cal["camera_matrix"] = k
            cal["distortion"] = dist
        trial = dict(cam, calibration=cal)
        model = zn.parse_cell(dict(data, cameras=[trial if c is cam else c for c in cams]),
                              args.file).camera_models[args.camera]
        errors = geo.reprojection_errors_px(model.homography, model.undistort_px(pairs[:, :2]),
                                            pairs[:, 2:4])
    for n, e in enumerate(errors):
        print(f"pair {n + 1}: ({pairs[n, 0]:g}, {pairs[n, 1]:g}) px  error {e:.3f} px")
    rms = float(np.sqrt(np.mean(np.square(errors))))
    print(f"reprojection error: RMS {rms:.3f} px, max {float(np.max(errors)):.3f} px "
          f"over {len(errors)} pairs")
    if rms > RMS_WARN_PX:  # a wrong pair (or unmodelled distortion) bends every zone
        worst = int(np.argmax(errors))
        print(f"monitor: warning: RMS {rms:.2f} px > {RMS_WARN_PX:g} px: a pair is likely wrong; "
              f"check pair {worst + 1} ({pairs[worst, 0]:g}, {pairs[worst, 1]:g}) px first "
              f"(error {errors[worst]:.2f} px), or model the lens distortion", file=sys.stderr)
    exact = 4 if not args.pnp else 3  # a homography has 8 unknowns, extrinsics 6
    if len(pairs) <= exact + 1:
        print(f"monitor: warning: {len(pairs)} pairs leave "
              f"{'no' if len(pairs) == exact else 'almost no'} redundancy: the fit passes "
              f"through them {'exactly' if len(pairs) == exact else 'nearly exactly'}, so the "
              "error above cannot show a wrong pair. Give 6 or more pairs, spread over the "
              "floor the zones use.", file=sys.stderr)
    if args.dry_run:
        return 0
    cam["calibration"] = cal
    write_zone_data(data, args.file)
    print(f"calibrated camera {args.camera} ({cal['type']})")
    return 0


def _solve_pnp(pairs: np.ndarray, k: Any, dist: list, args: argparse.Namespace
               ) -> tuple[dict, np.ndarray]:
    if k is None:
        raise ConfigError(f"calibrate --pnp: camera '{args.camera}' has no camera_matrix yet")
    if len(pairs) < 4:
        raise ConfigError(f"calibrate --pnp: needs at least 4 point pairs, got {len(pairs)}")
    img = pairs[:, :2].astype(np.float64)
    obj = np.c_[pairs[:, 2:4], pairs[:, 4] if pairs.shape[1] == 5 else np.zeros(len(pairs))]
    kk = np.array(k, dtype=float)
    dd = np.array(dist, dtype=float) if dist else np.zeros(5)
    ok, rvec, tvec = cv2.solvePnP(obj, img, kk, dd, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise ConfigError("calibrate --pnp: no solution (degenerate point pairs?)")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, kk, dd, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, kk, dd)
    errors = np.linalg.norm(proj.reshape(-1, 2) - img, axis=1)
    r, _ = cv2.Rodrigues(rvec)
    cal = {"type": "pinhole", "camera_matrix": kk.tolist(), "distortion": list(dist),
           "rotation": np.round(r, 9).tolist(),
           "translation_m": np.round(tvec.reshape(3), 9).tolist()}
    return cal, errors
