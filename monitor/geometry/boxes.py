"""Box algebra for person boxes: IoU, non-maximum suppression and merging.

Boxes are float arrays (N, 4) of ``x1, y1, x2, y2`` in one pixel frame. Everything here is a pure,
vectorised function: no I/O, no state.

Why merging: the research prototype saw two boxes drawn over one person, and a cell-wise
detector (our synthetic model) reports one box per grid cell a person covers. Boxes that overlap
strongly, lie mostly inside one another, or touch along a grid edge belong to one person and
become one box: their union (a safety monitor should err on the large side), with the highest
score.
"""

from __future__ import annotations

import numpy as np


def area(boxes: np.ndarray) -> np.ndarray:
    return np.clip(boxes[:, 2] - boxes[:, 0], 0, None) * np.clip(boxes[:, 3] - boxes[:, 1], 0, None)


def _intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    return np.clip(w, 0, None) * np.clip(h, 0, None)


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise intersection over union, shape (len(a), len(b))."""
    inter = _intersection(a, b)
    union = area(a)[:, None] + area(b)[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)


def ios_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise intersection over the smaller box's area."""
    inter = _intersection(a, b)
    smaller = np.minimum(area(a)[:, None], area(b)[None, :])
    return np.where(smaller > 0, inter / np.maximum(smaller, 1e-12), 0.0)


def gap_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise Chebyshev gap between boxes: 0 when they touch or overlap, else the larger of the
    horizontal and vertical clearances."""
    gx = np.maximum(a[:, None, 0], b[None, :, 0]) - np.minimum(a[:, None, 2], b[None, :, 2])
    gy = np.maximum(a[:, None, 1], b[None, :, 1]) - np.minimum(a[:, None, 3], b[None, :, 3])
    return np.clip(np.maximum(gx, gy), 0, None)


def nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Greedy non-maximum suppression. Returns the kept indices, best score first.

    Same rule as cv2.dnn.NMSBoxes: a box is dropped when its IoU with a kept, higher-scoring box
    is above ``iou_threshold``.
    """
    n = len(scores)
    if n == 0:
        return np.zeros((0,), np.int64)
    order = np.argsort(-scores, kind="stable")
    # conflict[i, j]: a better box j overlaps box i too much. Boxes without conflicts are kept
    # outright; the greedy pass walks only the conflicted ones (few, for person boxes).
    conflict = np.tril(iou_matrix(boxes[order], boxes[order]) > iou_threshold, k=-1)
    kept = np.ones(n, bool)
    for i in np.flatnonzero(conflict.any(axis=1)):
        kept[i] = not (conflict[i] & kept).any()
    return order[kept]


def connected_groups(adjacent: np.ndarray) -> np.ndarray:
    """Component label per node of a symmetric boolean adjacency matrix (labels 0..K-1)."""
    n = len(adjacent)
    labels = np.arange(n)
    if n == 0:
        return labels
    adj = adjacent | np.eye(n, dtype=bool)
    while True:  # min-label propagation; converges in (graph diameter) steps
        new = np.where(adj, labels[None, :], n).min(axis=1)
        new = new[new]  # pointer jumping halves the remaining steps
        if np.array_equal(new, labels):
            break
        labels = new
    return np.unique(labels, return_inverse=True)[1]


def merge_boxes(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float = 0.5,
                ios_threshold: float = 0.7, touch_px: float = 1.0,
                ) -> tuple[np.ndarray, np.ndarray]:
    """Merge boxes that belong to one person: IoU above ``iou_threshold``, intersection over the
    smaller box above ``ios_threshold``, or a gap of at most ``touch_px`` (touching along a grid
    edge or corner). Merging is transitive (a chain of overlapping boxes becomes one box).

    Returns (merged boxes as the union of each group, score = the group's maximum), sorted by
    score, highest first. ``touch_px < 0`` disables merging by touch.
    """
    if len(boxes) == 0:
        return boxes.reshape(0, 4), scores.reshape(0)
    if touch_px >= 0:  # overlapping boxes have gap 0, so this covers the IoU and IoS rules
        adjacent = gap_matrix(boxes, boxes) <= touch_px
    else:
        adjacent = (iou_matrix(boxes, boxes) > iou_threshold) | \
            (ios_matrix(boxes, boxes) > ios_threshold)
    labels = connected_groups(adjacent)
    k = labels.max() + 1
    merged = np.empty((k, 4), boxes.dtype)
    merged[:, 0] = np.full(k, np.inf)
    merged[:, 1] = np.full(k, np.inf)
    merged[:, 2] = np.full(k, -np.inf)
    merged[:, 3] = np.full(k, -np.inf)
    np.minimum.at(merged[:, 0], labels, boxes[:, 0])
    np.minimum.at(merged[:, 1], labels, boxes[:, 1])
    np.maximum.at(merged[:, 2], labels, boxes[:, 2])
    np.maximum.at(merged[:, 3], labels, boxes[:, 3])
    best = np.full(k, -np.inf, scores.dtype)
    np.maximum.at(best, labels, scores)
    order = np.argsort(-best, kind="stable")
    return merged[order], best[order]
