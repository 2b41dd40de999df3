"""Ground truth of a walk: where each person really stood in each frame of the video (a
generated walk has it, ``monitor.commission.walk_scene``; a recorded one does not).

With it, an entry starts at the first frame a person truly stands in the zone, whether or not
the detector found them there, so the walk's time to STOP includes the frames the detector
needed (a detector that misses the first frame inside shows one frame interval).

``truth.json``: ``{"fps": 5.0, "frames": [{"time_s": 0.0, "floor_m": [[x, y], ...],
"postures": ["standing", ...]}, ...]}``, one entry per video frame in order; ``floor_m`` in cell
metres (the zone file's frame). Pure apart from ``read_truth``/``write_truth``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from monitor.errors import InputError

TRUTH_FILE = "truth.json"


@dataclass(frozen=True)
class TruthFrame:
    time_s: float
    floor_m: tuple[tuple[float, float], ...]  # every person present, seen or hidden
    postures: tuple[str, ...] = ()


def truth_of(frames) -> tuple[TruthFrame, ...]:
    """From a scene's per-frame truth (``monitor.scene.cell.CellFrameTruth``)."""
    return tuple(TruthFrame(float(f.time_s), tuple((float(p.floor_m[0]), float(p.floor_m[1]))
                                                   for p in f.persons),
                            tuple(p.posture for p in f.persons)) for f in frames)


def write_truth(path: Path, frames: Sequence[TruthFrame], fps: float) -> None:
    data = {"fps": fps, "frames": [
        {"time_s": round(f.time_s, 4), "floor_m": [[round(x, 4), round(y, 4)]
                                                   for x, y in f.floor_m],
         "postures": list(f.postures)} for f in frames]}
    Path(path).write_text(json.dumps(data, indent=None, separators=(",", ":")) + "\n")


def read_truth(path: Path) -> tuple[TruthFrame, ...]:
    """A truth file, with one-line errors."""
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no such ground-truth file") from None
    except (ValueError, UnicodeDecodeError):
        raise InputError(f"{path}: not a ground-truth file (not JSON)") from None
    frames = data.get("frames") if isinstance(data, dict) else None
    if not isinstance(frames, list):
        raise InputError(f"{path}: not a ground-truth file (no frames list)")
    out = []
    for k, f in enumerate(frames):
        try:
            t = float(f["time_s"])
            pts = tuple((float(x), float(y)) for x, y in f["floor_m"])
            postures = tuple(str(p) for p in f.get("postures", ()))
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{path}: frame {k}: needs time_s and floor_m [[x, y], ...] "
                             "(metres)") from None
        if not math.isfinite(t) or not all(map(math.isfinite, (c for p in pts for c in p))):
            raise InputError(f"{path}: frame {k}: a number that is not finite")
        out.append(TruthFrame(t, pts, postures))
    return tuple(out)


def aligned(truth: Sequence[TruthFrame], times_s: Sequence[float], interval_s: float,
            name: str = TRUTH_FILE) -> tuple[TruthFrame, ...]:
    """The truth frame of each video frame (both in order); a truth for another video (other
    frame count, or a frame more than half an interval off) is a one-line error."""
    if len(truth) != len(times_s):
        raise InputError(f"{name}: {len(truth)} frames, the video has {len(times_s)}: the "
                         "ground truth of another video")
    tol = max(interval_s / 2, 1e-3)
    for k, (f, t) in enumerate(zip(truth, times_s, strict=True)):
        if abs(f.time_s - t) > tol:
            raise InputError(f"{name}: frame {k} at {f.time_s:g} s, the video's at {t:g} s: "
                             "the ground truth of another video")
    return tuple(truth)
