"""Detector accuracy against scene ground truth (pure; used by tests and `monitor model eval`).

A detection matches a person when its box contains the box of the person's visible pixels and no
edge lies more than ``tolerance_px`` outside it. For a cell-wise detector the tolerance is one
cell of the finest output grid mapped to frame pixels, plus 2 px: it cannot be tighter, and for a
safety monitor a box that errs on the large side is the right error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from monitor.scene import FrameTruth


@dataclass
class Accuracy:
    persons: int = 0
    matched: int = 0
    detections: int = 0
    false_detections: int = 0
    distractor_hits: int = 0
    single_box: int = 0  # persons covered by exactly one detection box
    ious: list[float] | None = None

    @property
    def recall(self) -> float:
        return self.matched / self.persons if self.persons else 1.0

    @property
    def precision(self) -> float:
        return (self.detections - self.false_detections) / self.detections \
            if self.detections else 1.0

    @property
    def mean_iou(self) -> float:
        return float(np.mean(self.ious)) if self.ious else 0.0

    @property
    def one_box_share(self) -> float:
        return self.single_box / self.persons if self.persons else 1.0


def cell_tolerance_px(frame_size: tuple[int, int], input_size: int = 416, cell: int = 16) -> float:
    """One cell of the finest grid (``cell`` model pixels) in frame pixels, plus 2 px."""
    scale = min(input_size / frame_size[0], input_size / frame_size[1])
    return cell / scale + 2.0


def _overlaps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return ~((a[:, 2] <= b[0]) | (a[:, 0] >= b[2]) | (a[:, 3] <= b[1]) | (a[:, 1] >= b[3]))


def score_frame(boxes: np.ndarray, truth: FrameTruth, tolerance_px: float,
                acc: Accuracy) -> Accuracy:
    """Add one frame's result to ``acc`` (greedy matching, persons in order)."""
    acc.ious = acc.ious if acc.ious is not None else []
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    used = np.zeros(len(boxes), bool)
    for person in truth.persons:
        g = np.asarray(person.box_px, float)
        inside = (boxes[:, :2] <= g[:2]).all(1) & (boxes[:, 2:] >= g[2:]).all(1)
        near = (g[:2] - boxes[:, :2] <= tolerance_px).all(1) & \
            (boxes[:, 2:] - g[2:] <= tolerance_px).all(1)
        candidates = np.flatnonzero(inside & near & ~used)
        acc.persons += 1
        acc.single_box += int(_overlaps(boxes, g).sum() == 1 and len(candidates) == 1)
        if len(candidates) == 0:
            continue
        k = candidates[0]
        used[k] = True
        acc.matched += 1
        b = boxes[k]
        inter = (min(b[2], g[2]) - max(b[0], g[0])) * (min(b[3], g[3]) - max(b[1], g[1]))
        union = (b[2] - b[0]) * (b[3] - b[1]) + (g[2] - g[0]) * (g[3] - g[1]) - inter
        acc.ious.append(inter / union)
    acc.detections += len(boxes)
    acc.false_detections += int((~used).sum())
    for d in truth.distractor_boxes_px:
        acc.distractor_hits += int(_overlaps(boxes[~used], np.asarray(d, float)).sum())
    return acc
