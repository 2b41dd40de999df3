"""Detector self-test: one image with one known person that the model must find.

What it catches: a blind model (no detections at all), corrupt or zeroed weights, all-zero or
NaN outputs, a wrong colour order or scaling (preprocessing), a wrong output layout. What it
cannot catch: a model that still finds this person but misses others (other clothing, poses,
lighting, sizes). See docs/models.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from monitor.errors import ConfigError
from monitor.geometry import boxes as box_ops
from monitor.scene import Figure, draw_figure
from monitor.types import Fault, Persons

FAULT_NAME = "detector_self_test"


@dataclass(frozen=True)
class SelfTestCase:
    """An image (BGR) and the box (x1 y1 x2 y2, its pixels) of the one person in it."""

    image: np.ndarray
    box_px: tuple[float, float, float, float]
    source: str  # "built-in" or the image file


def builtin_case(width: int = 640, height: int = 480) -> SelfTestCase:
    """A person of the synthetic model's kind (monitor.scene) standing on a plain grey floor."""
    image = np.full((height, width, 3), 120, np.uint8)
    figure = Figure((width * 0.45, height * 0.9), height * 0.6, phase=0.6)
    draw_figure(image, figure)
    ys, xs = np.nonzero((image != 120).any(axis=2))
    box = (float(xs.min()), float(ys.min()), float(xs.max() + 1), float(ys.max() + 1))
    return SelfTestCase(image, box, "built-in")


def load_case(image_path: str | Path, box: tuple[float, float, float, float]) -> SelfTestCase:
    """The user's self-test image; ConfigError when it cannot be read or the box is outside."""
    path = Path(image_path)
    image = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
    if image is None:
        raise ConfigError(f"detector.self_test_image: cannot read {path} as an image")
    h, w = image.shape[:2]
    if box[2] > w or box[3] > h:
        raise ConfigError(f"detector.self_test_box: {list(box)} lies outside the {w}x{h} "
                          f"image {path}")
    return SelfTestCase(image, tuple(float(v) for v in box), str(path))


def check(case: SelfTestCase, detect: Callable[[np.ndarray], Persons], min_iou: float,
          ) -> Fault | None:
    """Run ``detect`` on the case; a STOP fault unless a person box covers the known one.

    Any exception of the detector (e.g. DetectorError on NaN outputs) is a failed self-test.
    """
    try:
        persons = detect(case.image)
    except Exception as exc:  # the detector failing is exactly what this test looks for
        return Fault(FAULT_NAME, f"self-test on the {case.source} image failed: "
                                 f"{_one_line(exc)}", True, "detector")
    want = np.asarray([case.box_px], np.float32)
    best = float(box_ops.iou_matrix(want, persons.boxes_px).max()) if len(persons) else 0.0
    if best >= min_iou:
        return None
    known = ", ".join(f"{v:.0f}" for v in case.box_px)
    found = "no person" if not len(persons) else f"{len(persons)} boxes, best overlap {best:.2f}"
    return Fault(FAULT_NAME, f"self-test missed the known person at [{known}] in the "
                             f"{case.source} image ({found}; needs {min_iou:.2f}): blind "
                             f"model, broken weights or wrong preprocessing", True, "detector")


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else "detector failed"
