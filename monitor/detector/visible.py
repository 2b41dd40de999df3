"""The visible fraction the detector needs: how much of a person must be in view to be found.

Beside the operating envelope (``monitor.detector.envelope``: light, contrast, noise, blur),
the other thing a camera's "seen free" rests on: a person standing behind a bench shows their
upper body only, a person behind a cabinet's edge one side. ``measure`` hides the self-test
figure in steps, from below (a fixture in front of the legs) and from one side, with a flat
fixture-coloured block over the hidden part, and runs the detector on each step
(``envelope.TRIALS`` shifted copies with their own noise). A trial finds the person when a
person box covers half of the visible part or more and its centre lies on the figure.

The stored value is the smallest visible share, from below and from the side, with recall at or
above the minimum, found by bisection over the steps (recall falls as less is in view), as the
envelope's limits are;
the larger of the two is the one ``person.visible_fraction`` must be at least
(``monitor.zones.visibility``: floor is seen only where that share of the smallest posture is
in view). Stored beside the model as ``MODEL.onnx.visible.json`` with the model's and the test
image's sha256, like the envelope.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from monitor.detector.envelope import TRIALS, case_digest, degrade, file_sha256
from monitor.detector.selftest import SelfTestCase
from monitor.errors import ModelError
from monitor.types import Persons

log = logging.getLogger(__name__)

FORMAT = 1
# visible shares tried, the whole figure first
SHARES = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.45, 0.4, 0.35, 0.3, 0.25, 0.2, 0.15, 0.1)
FIXTURE_BGR = (70, 95, 115)  # a bench's colour (never work wear)


@dataclass(frozen=True)
class VisibleFraction:
    """The smallest visible share of the test figure (from below, from the side) at which the
    model's recall stays >= ``min_recall``; ``needed`` is the larger."""

    from_below: float
    from_side: float
    min_recall: float
    source: str
    model_sha256: str = ""
    case_sha256: str = ""
    # direction -> ((share, recall), ...) as measured
    recall: dict[str, tuple[tuple[float, float], ...]] = field(default_factory=dict)

    @property
    def needed(self) -> float:
        return max(self.from_below, self.from_side)

    def table(self) -> str:
        lines = [f"visible fraction the model needs for recall >= {self.min_recall:g} on the "
                 f"{self.source} self-test figure: {self.needed:g} (from below "
                 f"{self.from_below:g}, from the side {self.from_side:g})"]
        for direction, rows in self.recall.items():
            cells = "  ".join(f"{s:g}:{r:.2f}" for s, r in rows)
            lines.append(f"  {direction:<6} {cells}")
        return "\n".join(lines)


def hide(image: np.ndarray, box: np.ndarray, share: float, direction: str
         ) -> tuple[np.ndarray, np.ndarray]:
    """The image with all but ``share`` of the figure's box hidden behind a flat block (from
    below: the lower part; from the side: the right part), and the visible part's box."""
    x1, y1, x2, y2 = (float(v) for v in box)
    out = image.copy()
    h, w = out.shape[:2]
    if direction == "below":
        cut = y1 + share * (y2 - y1)
        top, left, right, bottom = round(cut), round(x1 - 0.3 * (x2 - x1)), \
            round(x2 + 0.3 * (x2 - x1)), h
        visible = np.array([x1, y1, x2, cut], np.float32)
    else:
        cut = x1 + share * (x2 - x1)
        top, left, right, bottom = round(y1 - 0.05 * (y2 - y1)), round(cut), w, h
        visible = np.array([x1, y1, cut, y2], np.float32)
    if share < 1.0:
        out[max(0, top):bottom, max(0, left):min(w, right)] = FIXTURE_BGR
    return out, visible


def found(persons: Persons, visible: np.ndarray, whole: np.ndarray) -> bool:
    """A person box covers half of the visible part or more, its centre on the figure."""
    boxes = np.asarray(persons.boxes_px, np.float64).reshape(-1, 4)
    if not len(boxes):
        return False
    ix = np.clip(np.minimum(boxes[:, 2], visible[2]) - np.maximum(boxes[:, 0], visible[0]), 0,
                 None)
    iy = np.clip(np.minimum(boxes[:, 3], visible[3]) - np.maximum(boxes[:, 1], visible[1]), 0,
                 None)
    area = max(float((visible[2] - visible[0]) * (visible[3] - visible[1])), 1e-9)
    cx, cy = (boxes[:, 0] + boxes[:, 2]) / 2, (boxes[:, 1] + boxes[:, 3]) / 2
    on = (cx >= whole[0]) & (cx <= whole[2]) & (cy >= whole[1]) & (cy <= whole[3])
    return bool(np.any((ix * iy / area >= 0.5) & on))


def measure(detect: Callable[[np.ndarray], Persons], case: SelfTestCase, stride_px: float,
            min_recall: float, shares: tuple[float, ...] = SHARES,
            input_width: int | None = None) -> VisibleFraction:
    """Measure the visible fraction ``detect`` needs on ``case`` (module doc); ``stride_px``
    is the model's finest grid cell in pixels of its input (``input_width`` wide; None: the
    case image's). ModelError when the model misses the whole figure itself."""
    image = case.image
    if input_width:
        stride_px *= image.shape[1] / input_width
    whole = np.asarray(case.box_px, np.float32)
    limits: dict[str, float] = {}
    table: dict[str, tuple[tuple[float, float], ...]] = {}
    shifts = ((0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.25, 0.75))[:TRIALS]
    for n, direction in enumerate(("below", "side")):
        tested: dict[int, float] = {}

        def recall(k: int, n: int = n, direction: str = direction,
                   tested: dict[int, float] = tested) -> float:
            if k not in tested:
                hits = 0
                for t, (fx, fy) in enumerate(shifts):
                    dx, dy = fx * stride_px, fy * stride_px
                    m = np.float32([[1, 0, dx], [0, 1, dy]])
                    moved = cv2.warpAffine(image, m, (image.shape[1], image.shape[0]),
                                           borderMode=cv2.BORDER_REPLICATE)
                    box = whole + np.float32([dx, dy, dx, dy])
                    hidden, visible = hide(moved, box, shares[k], direction)
                    rng = np.random.default_rng(n * 1000 + k * 10 + t)
                    hits += found(detect(degrade(hidden, rng=rng)), visible, box)
                tested[k] = hits / len(shifts)
            return tested[k]

        if recall(0) < min_recall:
            raise ModelError(f"the model finds the {case.source} self-test figure in only "
                             f"{100 * tested[0]:.0f} % of {len(shifts)} shifted copies: no "
                             "visible fraction can be measured")
        # bisection over the steps (recall falls as less is in view): the last passing step
        # with the next one failing, in about log2(steps) + 1 runs
        lo, hi = 0, len(shares)
        if recall(len(shares) - 1) >= min_recall:
            lo = hi = len(shares) - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            lo, hi = (mid, hi) if recall(mid) >= min_recall else (lo, mid)
        limits[direction] = shares[lo]
        table[direction] = tuple((shares[k], tested[k]) for k in sorted(tested))
    return VisibleFraction(limits["below"], limits["side"], min_recall, case.source,
                           case_sha256=case_digest(case), recall=table)


def sidecar_path(model_path: str | Path) -> Path:
    """Where a model's visible fraction is stored: ``MODEL.onnx.visible.json`` beside it."""
    model_path = Path(model_path)
    return model_path.with_name(model_path.name + ".visible.json")


def to_json(value: VisibleFraction) -> str:
    data = asdict(value)
    data["recall"] = {k: [list(r) for r in v] for k, v in value.recall.items()}
    return json.dumps({"format": FORMAT, **data}, indent=1, sort_keys=True)


def from_json(text: str, where: str) -> VisibleFraction:
    """A measured visible fraction from its sidecar; ModelError naming ``where`` when bad."""
    try:
        data = json.loads(text)
        if data.pop("format", None) != FORMAT:
            raise ValueError("unknown format")
        data["recall"] = {k: tuple((float(s), float(r)) for s, r in v)
                          for k, v in data.get("recall", {}).items()}
        value = VisibleFraction(**data)
        if not all(isinstance(v, (int, float)) and 0 < v <= 1
                   for v in (value.from_below, value.from_side)):
            raise ValueError("a share is not in (0, 1]")
        return value
    except (ValueError, TypeError, AttributeError) as exc:
        raise ModelError(f"{where}: not a measured visible fraction ({exc}); remove it or run "
                         "'monitor model envelope'") from None


def for_detector(detector, min_recall: float, store: bool = True) -> VisibleFraction | None:
    """The visible fraction of a loaded ``monitor.detector.Detector``: the stored one when it
    is current, else measured (a few seconds) and stored beside the model when ``store``.
    None when the model has no self-test image."""
    case = detector.self_test_case
    if case is None:
        return None
    sha = file_sha256(detector.model_path)
    path = sidecar_path(detector.model_path)
    if path.is_file():
        value = from_json(path.read_text(), str(path))
        if value.model_sha256 == sha and value.case_sha256 == case_digest(case) \
                and value.min_recall == min_recall:
            return value
    value = measure(detector.detect, case, detector.finest_stride_px(), min_recall,
                    input_width=detector.layout.input_width)
    value = VisibleFraction(**{**asdict(value), "model_sha256": sha, "recall": value.recall})
    if store:
        try:
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text(to_json(value) + "\n")
            os.replace(tmp, path)
        except OSError as exc:
            log.warning("%s: visible fraction not stored (%s); measured again at the next "
                        "start", path, exc)
    return value
