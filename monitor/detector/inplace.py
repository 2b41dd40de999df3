"""The in-place detection check: can the model see a person *here, in this image*?

Every ``period_s`` (a few seconds) the test figure (the self-test image's person) is pasted
into a copy of a camera's newest frame, inside each protective zone's image region, matched to
the frame there: scaled to the region's height, its brightness scaled by the region's mean
luminance over the test image's, and the region's measured noise added. The detector runs on
that copy; the figure must be found (a person box covering half of the pasted box). A miss is a
STOP fault ``detector_blind_here`` ("cam0 cannot see a person in robot-protective in the
current image") that holds until the next check passes.

It costs one inference per camera per period, whatever its zones (about 2.4 % of the
inference at 15 fps and a 3 s period; ``benchmarks/inplace.py``). What it does not match: blur
(the envelope's limit judges it), the zone's lighting on a person rather than on the floor,
and postures or clothing other than the test figure's (docs/health.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from monitor.detector import imagestats
from monitor.detector.selftest import SelfTestCase
from monitor.types import Fault, Persons

FAULT_NAME = "detector_blind_here"
MIN_COVER = 0.5  # share of the pasted box a found person box must cover


@dataclass(frozen=True)
class Figure:
    """The test figure cut from its image: pixels, a mask of the person, the image's mean
    luminance (what the figure's brightness belongs to)."""

    pixels: np.ndarray  # BGR uint8, the box's crop
    mask: np.ndarray  # bool, True on the person
    background_mean: float

    @classmethod
    def from_case(cls, case: SelfTestCase) -> Figure:
        x1, y1, x2, y2 = (round(v) for v in case.box_px)
        crop = case.image[y1:y2, x1:x2].copy()
        grey = cv2.cvtColor(case.image, cv2.COLOR_BGR2GRAY)
        # the person: pixels unlike the image's most common colour (the built-in figure stands
        # on plain grey); a user's crop without such a background is pasted whole
        # each BGR pixel packed into one integer: a 1-D unique is ~20x faster than rows
        # (axis=0), which took 0.6 s of every `monitor run` start
        flat = case.image.reshape(-1, 3).astype(np.uint32)
        packed = (flat[:, 0] << 16) | (flat[:, 1] << 8) | flat[:, 2]
        values, counts = np.unique(packed, return_counts=True)
        top = int(values[counts.argmax()])
        common = np.array([top >> 16, (top >> 8) & 0xFF, top & 0xFF], case.image.dtype)
        mask = (crop != common).any(axis=2)
        if counts.max() < 0.3 * grey.size or not mask.any():
            mask = np.ones(crop.shape[:2], bool)
        outside = grey.copy()
        outside[y1:y2, x1:x2] = 0
        n = grey.size - crop.shape[0] * crop.shape[1]
        mean = float(outside.sum()) / n if n > 0 else float(grey.mean())
        return cls(crop, mask, max(mean, 1.0))


def paste(frame_bgr: np.ndarray, figure: Figure, box: tuple[int, int, int, int],
          rng: np.random.Generator) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """A copy of the frame with the figure standing in ``box`` (x1 y1 x2 y2, frame px),
    matched to the frame's local brightness and noise there; and the pasted figure's box."""
    x1, y1, x2, y2 = box
    height = y2 - y1
    fh, fw = figure.pixels.shape[:2]
    scale = height / fh
    width = max(2, round(fw * scale))
    cx = (x1 + x2) // 2
    px1 = max(0, min(frame_bgr.shape[1] - width, cx - width // 2))
    px2 = px1 + width
    local = cv2.cvtColor(frame_bgr[y1:y2, max(0, x1):x2], cv2.COLOR_BGR2GRAY)
    gain = imagestats.luminance(local)[0] / figure.background_mean
    sigma = imagestats.noise_sigma(local)
    pixels = cv2.resize(figure.pixels, (width, height), interpolation=cv2.INTER_AREA)
    mask = cv2.resize(figure.mask.astype(np.uint8), (width, height),
                      interpolation=cv2.INTER_NEAREST).astype(bool)
    fig = pixels.astype(np.float32) * gain
    if sigma > 0:
        fig += rng.normal(0.0, sigma, fig.shape).astype(np.float32)
    out = frame_bgr.copy()
    region = out[y1:y2, px1:px2]
    region[mask] = np.clip(np.rint(fig[mask]), 0, 255).astype(np.uint8)
    ys, xs = np.nonzero(mask)
    return out, (float(px1 + xs.min()), float(y1 + ys.min()), float(px1 + xs.max() + 1),
                 float(y1 + ys.max() + 1))


def place(polygon_px: np.ndarray, frame_size: tuple[int, int], min_height: float
          ) -> tuple[int, int, int, int] | None:
    """Where the figure stands in a zone region: the region's bounding box, at least
    ``min_height`` px tall (a person smaller than a few grid cells is not the question), inside
    the frame; None when the frame cannot hold it."""
    width, height = frame_size
    x, y, w, h = cv2.boundingRect(np.round(np.asarray(polygon_px)).astype(np.int32))
    x1, x2 = max(0, x), min(width, x + w)
    y2 = min(height, y + h)
    y1 = max(0, min(y, y2 - math.ceil(min_height)))
    if x2 - x1 < 4 or y2 - y1 < min_height:
        return None
    return x1, y1, x2, y2


class InPlaceCheck:
    """The in-place check of every camera's protective zones (``zones``: camera id ->
    ``(zone_id, polygon_px)`` pairs). ``detect`` runs the model on a BGR image."""

    def __init__(self, case: SelfTestCase, detect: Callable[[np.ndarray], Persons],
                 zones: Mapping[str, Sequence[tuple[str, np.ndarray]]], period_s: float,
                 min_height_px: float = 48.0) -> None:
        self.figure = Figure.from_case(case)
        self.detect = detect
        self.zones = {cid: list(z) for cid, z in zones.items()}
        self.period_s = period_s
        self.min_height_px = min_height_px
        self._next: dict[str, float] = {}
        self.faults: dict[str, Fault] = {}  # per camera, until its next check passes
        self.runs = 0

    def due(self, camera_id: str, now: float) -> bool:
        return camera_id in self.zones and now >= self._next.get(camera_id, -math.inf)

    def check(self, camera_id: str, frame_bgr: np.ndarray, now: float) -> Fault | None:
        """Paste into every protective zone of this camera's frame, detect once, judge; the
        fault names the zones where the figure was not found (None: found in all)."""
        self._next[camera_id] = now + self.period_s
        fault = None
        h, w = frame_bgr.shape[:2]
        rng = np.random.default_rng(self.runs)
        # one copy with a figure in every zone, one inference: the cost does not grow with
        # the zones (figures of overlapping zones merge into one box, which covers both)
        image, pasted = frame_bgr, []
        for zone_id, polygon in self.zones.get(camera_id, ()):
            box = place(polygon, (w, h), self.min_height_px)
            if box is not None:
                image, where = paste(image, self.figure, box, rng)
                pasted.append((zone_id, where))
        if pasted:
            self.runs += 1
            try:
                boxes = self.detect(image).boxes_px
            except Exception as exc:  # the detector failing here is a blind zone too
                zone = pasted[0][0]
                return self._keep(camera_id, Fault(
                    FAULT_NAME, f"{camera_id} cannot see a person in {zone}: the detector "
                    f"failed ({str(exc)[:120]})", True, camera_id))
            missed = [z for z, where in pasted if covered(where, boxes) < MIN_COVER]
            if missed:
                fault = Fault(FAULT_NAME, f"{camera_id} cannot see a person in "
                              f"{', '.join(missed)} in the current image (the test figure "
                              "pasted there, matched to its light and noise, was not found)",
                              True, camera_id)
        return self._keep(camera_id, fault)

    def _keep(self, camera_id: str, fault: Fault | None) -> Fault | None:
        if fault is None:
            self.faults.pop(camera_id, None)
        else:
            self.faults[camera_id] = fault
        return fault


def covered(box: tuple[float, float, float, float], boxes_px: np.ndarray) -> float:
    """The largest share of ``box`` one of ``boxes_px`` covers."""
    if not len(boxes_px):
        return 0.0
    b = np.asarray(boxes_px, np.float32).reshape(-1, 4)
    iw = np.clip(np.minimum(b[:, 2], box[2]) - np.maximum(b[:, 0], box[0]), 0, None)
    ih = np.clip(np.minimum(b[:, 3], box[3]) - np.maximum(b[:, 1], box[1]), 0, None)
    area = max((box[2] - box[0]) * (box[3] - box[1]), 1e-6)
    return float((iw * ih).max()) / area
