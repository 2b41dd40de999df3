"""Image conditions against the model's operating envelope (monitor/detector/envelope.py).

Per frame, on the health checks' small grey image: mean luminance, spread (std / mean),
noise and sharpness (``monitor.detector.imagestats``), for the whole view and for each protective
zone's image region, and the clipped share (glare: a person standing in a saturated patch is
gone) of each protective zone's region. Outside the envelope is a STOP fault
``detector_envelope`` naming the camera, the region and the measure ("cam0: too dim for the
detector: mean luminance 38, envelope >= 55"); inside but within ``envelope_margin`` of an
edge is a warning alert.

The envelope is in degradations (gain, contrast, noise, blur); a camera's thresholds are its
*reference image's* measures at those degradations (``limit_measures``): the reference is its
normal view, so "0.75 of its brightness" becomes a mean luminance. A camera without a reference
is judged by the envelope's measures of the test figure's own image, and not for blur
(sharpness depends on what an image shows).

Saturation is judged per protective zone region (a lamp elsewhere in the view hides nobody in
the zone), with or without a reference: the envelope's ``max_saturated`` (the clipped share of
the test image with the largest glare band the model sees through), on top of what the
reference's own region already has clipped (its normal view: a white sign, a lamp).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from monitor.detector import imagestats
from monitor.detector.envelope import Envelope, limit_measures, limits_of
from monitor.types import Alert, Fault

ENVELOPE = "detector_envelope"  # STOP fault: outside the envelope
ENVELOPE_NEAR = "detector_envelope_near"  # warning: within the margin of an edge
ENVELOPE_CLEARED = "detector_envelope_near_cleared"

# (measure, limit key, "min" or "max", words for the fault)
CHECKS = (
    ("mean", "min_mean", "min", "too dim for the detector: mean luminance"),
    ("mean", "max_mean", "max", "too bright for the detector: mean luminance"),
    ("spread", "min_spread", "min", "too little contrast for the detector: spread"),
    ("noise", "max_noise", "max", "too noisy for the detector: noise sigma"),
    ("sharpness", "min_sharpness", "min", "too blurred for the detector: sharpness"),
    ("saturated", "max_saturated", "max", "too much glare for the detector: saturated share"),
)


@dataclass(frozen=True)
class Region:
    """A part of the view judged on its own: its name and box in analysis pixels."""

    name: str
    box: tuple[int, int, int, int]  # x1, y1, x2, y2 (exclusive)


@dataclass(frozen=True)
class Judgement:
    """One frame's verdict: the first measure outside (reason) or near an edge (near)."""

    outside: str = ""
    near: str = ""


def camera_limits(envelope: Envelope, reference_small_bgr: np.ndarray | None,
                  frame_size: tuple[int, int], analysis_width: int,
                  regions: Sequence[Region] = ()) -> dict[str, dict[str, float]]:
    """Thresholds per region ("view" and each zone region) in this camera's measures. Without
    a reference: the envelope's absolute measures for the view, and its saturation limit for
    each zone region."""
    glare = envelope.absolute.get("max_saturated")
    view = {k: v for k, v in envelope.absolute.items() if k != "max_saturated"}
    if reference_small_bgr is None:
        return {"view": view, **({r.name: {"max_saturated": glare} for r in regions}
                                 if glare is not None else {})}
    width, height = frame_size
    detector_scale = min(envelope.input_width / width, envelope.input_height / height)
    blur_scale = (analysis_width / width) / detector_scale  # analysis px per input px
    limits = limits_of(envelope)
    out = {"view": limit_measures(reference_small_bgr, limits, blur_scale)}
    for r in regions:
        x1, y1, x2, y2 = r.box
        patch = reference_small_bgr[y1:y2, x1:x2]
        out[r.name] = limit_measures(patch, limits, blur_scale)
        if glare is not None:
            clipped = imagestats.saturated(cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY))
            out[r.name]["max_saturated"] = min(1.0, clipped + glare)
    return out


def measures(grey: np.ndarray, regions: Sequence[Region]) -> dict[str, dict[str, float]]:
    """The measures of the view and of each region of one frame's small grey image."""
    out = {"view": imagestats.conditions(grey)}
    for r in regions:
        x1, y1, x2, y2 = r.box
        out[r.name] = imagestats.conditions(grey[y1:y2, x1:x2])
    return out


def judge(values: dict[str, dict[str, float]], limits: dict[str, dict[str, float]],
          margin: float, camera_id: str) -> Judgement:
    """Outside any limit: the fault's reason; else within ``margin`` (a fraction) of one: the
    alert's text. A measure that is not a finite number is outside."""
    near = ""
    for region, lim in limits.items():
        got = values.get(region)
        where = camera_id if region == "view" else f"{camera_id} ({region})"
        for measure, key, side, words in CHECKS:
            if key not in lim:
                continue
            edge = lim[key]
            v = got.get(measure, float("nan")) if got else float("nan")
            bad = not (v >= edge) if side == "min" else not (v <= edge)
            sign = ">=" if side == "min" else "<="
            text = f"{where}: {words} {_num(v)}, envelope {sign} {_num(edge)}"
            if bad:
                return Judgement(outside=text)
            close = v < edge * (1 + margin) if side == "min" else v > edge * (1 - margin)
            if close and not near:
                near = text.replace("too ", "near the edge: ", 1)
    return Judgement(near=near)


def zone_regions(zones: Sequence[tuple[str, np.ndarray]], scale: float,
                 small_size: tuple[int, int], min_px: int = 8) -> list[Region]:
    """Boxes (analysis pixels) of zone polygons given in full-resolution pixels; boxes smaller
    than ``min_px`` on a side are left out (too few pixels for a statistic)."""
    sw, sh = small_size
    out = []
    for name, poly in zones:
        x, y, w, h = cv2.boundingRect(np.round(np.asarray(poly) / scale).astype(np.int32))
        x1, y1, x2, y2 = max(0, x), max(0, y), min(sw, x + w), min(sh, y + h)
        if x2 - x1 >= min_px and y2 - y1 >= min_px:
            out.append(Region(name, (x1, y1, x2, y2)))
    return out


class EnvelopeWatch:
    """The envelope check of one camera, fed every frame's small grey image. The STOP fault
    holds for every frame outside (no hold-off: the first dim frame may already hide a
    person); the warning is an alert when the view comes near an edge and when it leaves it
    for ``clear_s``."""

    def __init__(self, envelope: Envelope, camera_id: str, margin: float, clear_s: float):
        self.envelope = envelope
        self.camera_id = camera_id
        self.margin = margin
        self.clear_s = clear_s
        self.limits: dict[str, dict[str, float]] = {}
        self.regions: list[Region] = []
        self._near_active = False
        self._fine_since: float | None = None

    def prepare(self, reference_small_bgr: np.ndarray | None, frame_size: tuple[int, int],
                analysis_width: int, regions: Sequence[Region]) -> None:
        # without a reference a zone region is judged for saturation only (the envelope's
        # other absolute measures are of the test image's whole view, not of a floor patch)
        self.regions = list(regions)
        self.limits = camera_limits(self.envelope, reference_small_bgr, frame_size,
                                    analysis_width, self.regions)

    def check(self, grey: np.ndarray, now: float) -> tuple[Fault | None, Alert | None,
                                                          dict[str, float]]:
        values = measures(grey, self.regions)
        verdict = judge(values, self.limits, self.margin, self.camera_id)
        flat = {f"env_{k}": round(v, 3) for k, v in values["view"].items()}
        fault = Fault(ENVELOPE, verdict.outside, True, self.camera_id) \
            if verdict.outside else None
        alert = None
        if verdict.outside or verdict.near:
            self._fine_since = None
            if not self._near_active:
                self._near_active = True
                alert = Alert(ENVELOPE_NEAR, "warning", verdict.outside or verdict.near,
                              self.camera_id, now, None, flat)
        elif self._near_active:
            self._fine_since = now if self._fine_since is None else self._fine_since
            if now - self._fine_since >= self.clear_s:
                self._near_active = False
                alert = Alert(ENVELOPE_CLEARED, "info", f"{self.camera_id}: image conditions "
                              "well inside the detector's envelope again", self.camera_id, now,
                              None, flat)
        return fault, alert, flat


def _num(v: float) -> str:
    return f"{v:.0f}" if abs(v) >= 10 else f"{v:.2f}"
