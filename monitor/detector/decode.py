"""Model outputs to person boxes (x1 y1 x2 y2, model-input pixels) and scores. Pure functions.

Every decoder keeps the candidates whose score reaches ``min_score`` (the configured threshold,
whatever it is), for the person classes of the layout; a candidate's score is the best of its
person classes.
"""

from __future__ import annotations

import math

import numpy as np

from monitor.detector.layouts import ModelLayout
from monitor.errors import DetectorError


def check_finite(outputs: list[np.ndarray], names: list[str]) -> None:
    """DetectorError when any floating-point output holds NaN or infinity.

    A broken model (NaN weights, overflow) must never read as "no persons"."""
    for name, out in zip(names, outputs, strict=False):
        arr = np.asarray(out)
        if arr.dtype.kind == "f" and not np.isfinite(arr).all():
            bad = int(arr.size - np.count_nonzero(np.isfinite(arr)))
            raise DetectorError(f"model output {name!r} has {bad} NaN or infinite values: the "
                                f"model or its weights are broken")


def _sigmoid(x: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        return 1.0 / (1.0 + np.exp(-x))


def _logit(p: float) -> float:
    """The raw value whose sigmoid is p (-inf for 0, +inf for 1)."""
    if p <= 0.0:
        return -math.inf
    if p >= 1.0:
        return math.inf
    return math.log(p / (1.0 - p))


def _concat(boxes: list[np.ndarray], scores: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    if not boxes:
        return np.zeros((0, 4), np.float32), np.zeros((0,), np.float32)
    return (np.concatenate(boxes).astype(np.float32),
            np.concatenate(scores).astype(np.float32))


def _cxcywh(rows: np.ndarray) -> np.ndarray:
    cx, cy, w, h = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3]
    return np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], 1)


def _grid(head: np.ndarray, nhwc: bool) -> tuple[int, int]:
    return (head.shape[1], head.shape[2]) if nhwc else (head.shape[2], head.shape[3])


def decode_darknet(heads: list[np.ndarray], layout: ModelLayout, min_score: float = 0.0,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Raw YOLOv3 heads to person boxes and scores.

    Each head is 1x(A*(5+C))xGyxGx (or NHWC); per anchor the channels are tx ty tw th obj classes.
    Box centre = (sigmoid(t) + cell) * stride, size = anchor * exp(t), score = obj * class.
    Grids need not be square (a 608x352 input gives 19x11 and 38x22 heads).
    """
    out_boxes, out_scores = [], []
    per = 5 + layout.num_classes
    person = [5 + c for c in layout.persons]
    # score = sig(obj) * sig(cls) >= t needs both logits >= logit(t): a cheap exact pre-filter
    floor = _logit(min_score) - 1e-6
    order = sorted(range(len(heads)), key=lambda i: _grid(heads[i], layout.heads_nhwc)[0])
    for rank, i in enumerate(order):
        head = heads[i][0]
        if layout.heads_nhwc:
            head = np.moveaxis(head, -1, 0)
        gy, gx = head.shape[1:]
        mask = layout.masks[rank]
        head = head.reshape(len(mask), per, gy, gx)
        cls = head[:, person].max(axis=1)
        a, y, x = np.nonzero((head[:, 4] >= floor) & (cls >= floor))
        if len(a) == 0:
            continue
        score = _sigmoid(head[a, 4, y, x]) * _sigmoid(cls[a, y, x])
        sx, sy = layout.input_width / gx, layout.input_height / gy
        t = head[a, :4, y, x]
        anchors = np.asarray(layout.anchors, np.float32)[np.asarray(mask)[a]]
        cx = (_sigmoid(t[:, 0]) + x) * sx
        cy = (_sigmoid(t[:, 1]) + y) * sy
        with np.errstate(over="ignore"):  # an overflow is an infinite box: refused later
            bw = anchors[:, 0] * np.exp(t[:, 2])
            bh = anchors[:, 1] * np.exp(t[:, 3])
        out_boxes.append(np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], 1))
        out_scores.append(score)
    return _concat(out_boxes, out_scores)


def decode_yolov5(out: np.ndarray, layout: ModelLayout, min_score: float = 0.0,
                  ) -> tuple[np.ndarray, np.ndarray]:
    rows = out[0]
    scores = rows[:, 4] * rows[:, [5 + c for c in layout.persons]].max(axis=1)
    keep = scores >= min_score
    return _cxcywh(rows[keep]).astype(np.float32), scores[keep].astype(np.float32)


def decode_yolov8(out: np.ndarray, layout: ModelLayout, min_score: float = 0.0,
                  ) -> tuple[np.ndarray, np.ndarray]:
    cols = out[0]  # (4 + C, N)
    scores = cols[[4 + c for c in layout.persons]].max(axis=0)
    keep = scores >= min_score
    return _cxcywh(cols[:4, keep].T).astype(np.float32), scores[keep].astype(np.float32)


def decode_end2end(out: np.ndarray, layout: ModelLayout, min_score: float = 0.0,
                   ) -> tuple[np.ndarray, np.ndarray]:
    rows = out[0]
    person = np.isin(np.rint(rows[:, 5]), layout.persons)
    keep = person & (rows[:, 4] >= min_score) & (rows[:, 4] > 0)  # score 0: padding rows
    return rows[keep, :4].astype(np.float32), rows[keep, 4].astype(np.float32)


def decode_yolox(out: np.ndarray, layout: ModelLayout, min_score: float = 0.0,
                 ) -> tuple[np.ndarray, np.ndarray]:
    rows = out[0]
    grids, strides = [], []
    for s in layout.strides:
        gh, gw = layout.input_height // s, layout.input_width // s
        yy, xx = np.mgrid[0:gh, 0:gw]
        grids.append(np.stack([xx.ravel(), yy.ravel()], 1))
        strides.append(np.full(gh * gw, s))
    grid = np.concatenate(grids).astype(np.float32)
    stride = np.concatenate(strides).astype(np.float32)[:, None]
    if len(grid) != len(rows):
        raise DetectorError(f"yolox output has {len(rows)} rows, the {layout.input_width}x"
                            f"{layout.input_height} grid {len(grid)}")
    scores = rows[:, 4] * rows[:, [5 + c for c in layout.persons]].max(axis=1)
    keep = scores >= min_score
    r = rows[keep]
    xy = (r[:, :2] + grid[keep]) * stride[keep]
    with np.errstate(over="ignore"):
        wh = np.exp(r[:, 2:4]) * stride[keep]
    return _cxcywh(np.concatenate([xy, wh], 1)).astype(np.float32), scores[keep].astype(np.float32)


def decode_zoo(outputs: list[np.ndarray], layout: ModelLayout, min_score: float = 0.0,
               ) -> tuple[np.ndarray, np.ndarray]:
    """ONNX Model Zoo tiny-yolov3: boxes (1,N,4) y1 x1 y2 x2 in frame pixels, scores (1,C,N),
    selected indices (K,3) or (1,K,3) of (batch, class, box)."""
    boxes, scores, indices = outputs
    idx = indices.reshape(-1, 3).astype(np.int64)
    idx = idx[(idx[:, 0] >= 0) & np.isin(idx[:, 1], layout.persons)]
    b = boxes[0, idx[:, 2]][:, [1, 0, 3, 2]]
    s = scores[0, idx[:, 1], idx[:, 2]]
    keep = s >= min_score
    return b[keep].astype(np.float32), s[keep].astype(np.float32)


def decode(outputs: list[np.ndarray], layout: ModelLayout, min_score: float = 0.0,
           ) -> tuple[np.ndarray, np.ndarray]:
    """Dispatch to the decoder of ``layout.kind``: person boxes in input pixels and scores."""
    if layout.kind == "darknet":
        return decode_darknet(outputs, layout, min_score)
    if layout.kind == "zoo":
        return decode_zoo(outputs, layout, min_score)
    decoder = {"yolov5": decode_yolov5, "yolov8": decode_yolov8, "end2end": decode_end2end,
               "yolox": decode_yolox}[layout.kind]
    return decoder(outputs[0], layout, min_score)
