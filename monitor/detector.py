"""Person detector: any tiny-YOLO style ONNX model through onnxruntime.

The output layout is found from the model's shapes and metadata (or named explicitly):

==============  =====================================================  ======================
layout          outputs                                                input expected
==============  =====================================================  ======================
darknet         2 or 3 raw heads 1x(A*(5+C))xGxG (NCHW) or 1xGxGx(..)  RGB/255, grey pad 0.5
yolov5          1xNx(5+C): cx cy w h obj classes (sigmoided)           RGB/255, pad 114
yolov8          1x(4+C)xN: cx cy w h classes (YOLOv8 / YOLO11)         RGB/255, pad 114
end2end         1xKx6: x1 y1 x2 y2 score class                         RGB/255, pad 114
zoo             ONNX Model Zoo tiny-yolov3 (inputs input_1,            RGB/255, pad 0.5
                image_shape; NMS inside the graph)
yolox           1xNx(5+C), raw grid-relative boxes, N = cells          BGR 0..255, pad 114,
                                                                       top-left aligned
==============  =====================================================  ======================

Boxes come back in the original frame's pixels (letterbox undone), person class only, after a
score threshold, a top-k cap, NMS and merging (``monitor.boxes``).
"""

from __future__ import annotations

import contextlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from monitor import boxes as box_ops
from monitor.errors import InputError, ModelError
from monitor.types import FrameInfo, Persons

LAYOUTS = ("darknet", "yolov5", "yolov8", "end2end", "zoo", "yolox")
# Darknet defaults: tiny-YOLOv3 (2 heads) and YOLOv3 (3 heads); coarse head first.
TINY_ANCHORS = ((10, 14), (23, 27), (37, 58), (81, 82), (135, 169), (344, 319))
TINY_MASKS = ((3, 4, 5), (1, 2, 3))
V3_ANCHORS = ((10, 13), (16, 30), (33, 23), (30, 61), (62, 45), (59, 119), (116, 90),
              (156, 198), (373, 326))
V3_MASKS = ((6, 7, 8), (3, 4, 5), (0, 1, 2))


@dataclass(frozen=True)
class Letterbox:
    """How a frame was fitted into the model input: input = frame * scale + (pad_x, pad_y)."""

    scale: float
    pad_x: float
    pad_y: float

    def to_frame(self, boxes: np.ndarray) -> np.ndarray:
        out = boxes.astype(np.float32, copy=True)
        out[:, [0, 2]] = (out[:, [0, 2]] - self.pad_x) / self.scale
        out[:, [1, 3]] = (out[:, [1, 3]] - self.pad_y) / self.scale
        return out


@dataclass(frozen=True)
class ModelLayout:
    """What the detector knows about a model's input and output."""

    kind: str
    input_name: str
    input_width: int
    input_height: int
    input_nhwc: bool = False
    rgb: bool = True
    scale: float = 1 / 255.0
    pad_value: int = 114  # 0..255, before scaling
    centered: bool = True
    num_classes: int = 80
    person_class: int = 0
    anchors: tuple[tuple[float, float], ...] = ()
    masks: tuple[tuple[int, ...], ...] = ()
    heads_nhwc: bool = False
    strides: tuple[int, ...] = (8, 16, 32)
    names: dict[int, str] = field(default_factory=dict)


@dataclass(frozen=True)
class DetectorConfig:
    score_threshold: float = 0.5  # the seeds' value: it trades missed persons against false stops
    nms_iou: float = 0.45
    top_k: int = 512  # candidates kept before NMS; more is reported as an overflow fault
    merge_iou: float = 0.5
    merge_ios: float = 0.7
    merge_touch_px: float = 1.0  # in model-input pixels; < 0 disables merging by touch
    threads: int = 2
    input_size: int = 416  # for models with a dynamic input size
    layout: str | None = None  # force a layout instead of detecting it
    anchors: tuple[tuple[float, float], ...] | None = None  # darknet: override anchors
    masks: tuple[tuple[int, ...], ...] | None = None  # darknet: override anchor masks
    # How far a box's bottom edge may lie below the real feet, in cells of the finest output
    # grid: the zone checks also test the feet this much higher (see zones.check_persons).
    foot_uncertainty_cells: float = 1.0
    # onnxruntime's workers spin after each run by default; on a 2-core box that steals the CPU
    # the rest of the pipeline (video decode, health) needs right after inference.
    spin_wait: bool = False

    def __post_init__(self) -> None:
        from monitor.errors import ConfigError

        if not 0.0 <= self.score_threshold <= 1.0:
            raise ConfigError(f"detector.score_threshold: {self.score_threshold} not in [0, 1]")
        if self.top_k < 1 or self.threads < 1 or self.input_size < 32:
            raise ConfigError("detector.top_k, threads must be >= 1 and input_size >= 32")
        if not 0.0 <= self.foot_uncertainty_cells <= 10.0:
            raise ConfigError("detector.foot_uncertainty_cells: must be within [0, 10]")


@dataclass(frozen=True)
class Detection:
    """One detect call: the persons, stage times (ms) and whether candidates were capped."""

    persons: Persons
    preprocess_ms: float
    inference_ms: float
    decode_ms: float
    candidates: int
    overflow: bool


# ----------------------------------------------------------------------------- preprocessing


class Letterboxer:
    """Fits frames into the model input keeping the aspect ratio, reusing one uint8 canvas.

    The padding is painted only when the frame geometry changes, and only the image region of
    the float tensor is converted, so a call costs one resize and one conversion of the visible
    pixels. The returned tensor is reused by the next call.
    """

    def __init__(self, layout: ModelLayout) -> None:
        self.layout = layout
        self._canvas = np.full((layout.input_height, layout.input_width, 3), layout.pad_value,
                               np.uint8)
        self._geometry: tuple[int, int, int, int] | None = None
        self._tensor = np.empty((1, 3, layout.input_height, layout.input_width), np.float32)

    def __call__(self, image_bgr: np.ndarray) -> tuple[np.ndarray, Letterbox]:
        """Returns (NCHW or NHWC float32 tensor, the letterbox)."""
        layout = self.layout
        h, w = image_bgr.shape[:2]
        iw, ih = layout.input_width, layout.input_height
        scale = min(iw / w, ih / h)
        nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
        px, py = ((iw - nw) // 2, (ih - nh) // 2) if layout.centered else (0, 0)
        if self._geometry != (nw, nh, px, py):
            self._canvas[:] = layout.pad_value
            self._tensor[:] = np.float32(layout.pad_value * layout.scale)
            self._geometry = (nw, nh, px, py)
        canvas = self._canvas
        view = canvas[py:py + nh, px:px + nw]
        cv2.resize(image_bgr, (nw, nh), dst=view, interpolation=cv2.INTER_LINEAR)
        box = Letterbox(scale, float(px), float(py))
        if layout.input_nhwc:
            rgb = cv2.cvtColor(canvas, cv2.COLOR_BGR2RGB) if layout.rgb else canvas
            return (rgb.astype(np.float32) * np.float32(layout.scale))[None], box
        planes = view.transpose(2, 0, 1)  # HWC -> CHW view, BGR
        np.multiply(planes[::-1] if layout.rgb else planes, np.float32(layout.scale),
                    out=self._tensor[0, :, py:py + nh, px:px + nw], casting="unsafe")
        return self._tensor, box


def letterbox(image_bgr: np.ndarray, layout: ModelLayout) -> tuple[np.ndarray, Letterbox]:
    """One-off letterbox (see :class:`Letterboxer`)."""
    return Letterboxer(layout)(image_bgr)


# ----------------------------------------------------------------------------- decoding


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def decode_darknet(heads: list[np.ndarray], layout: ModelLayout,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Raw YOLOv3 heads to person boxes (x1 y1 x2 y2, input pixels) and scores.

    Each head is 1x(A*(5+C))xGyxGx (or NHWC); per anchor the channels are tx ty tw th obj classes.
    Box centre = (sigmoid(t) + cell) * stride, size = anchor * exp(t), score = obj * class.
    """
    out_boxes, out_scores = [], []
    per = 5 + layout.num_classes
    order = sorted(range(len(heads)), key=lambda i: _grid(heads[i], layout.heads_nhwc)[0])
    for rank, i in enumerate(order):
        head = heads[i][0]
        if layout.heads_nhwc:
            head = np.moveaxis(head, -1, 0)
        gy, gx = head.shape[1:]
        mask = layout.masks[rank]
        head = head.reshape(len(mask), per, gy, gx)
        # cheap pre-filter on the raw logits (sigmoid > 1e-3); the score threshold comes later
        a, y, x = np.nonzero((head[:, 4] > -6.9) & (head[:, 5 + layout.person_class] > -6.9))
        if len(a) == 0:
            continue
        score = _sigmoid(head[a, 4, y, x]) * _sigmoid(head[a, 5 + layout.person_class, y, x])
        sx, sy = layout.input_width / gx, layout.input_height / gy
        t = head[a, :4, y, x]
        anchors = np.asarray(layout.anchors, np.float32)[np.asarray(mask)[a]]
        cx = (_sigmoid(t[:, 0]) + x) * sx
        cy = (_sigmoid(t[:, 1]) + y) * sy
        bw = anchors[:, 0] * np.exp(t[:, 2])
        bh = anchors[:, 1] * np.exp(t[:, 3])
        out_boxes.append(np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], 1))
        out_scores.append(score)
    return _concat(out_boxes, out_scores)


def _grid(head: np.ndarray, nhwc: bool) -> tuple[int, int]:
    return (head.shape[1], head.shape[2]) if nhwc else (head.shape[2], head.shape[3])


def _concat(boxes: list[np.ndarray], scores: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    if not boxes:
        return np.zeros((0, 4), np.float32), np.zeros((0,), np.float32)
    return (np.concatenate(boxes).astype(np.float32),
            np.concatenate(scores).astype(np.float32))


def _cxcywh(rows: np.ndarray) -> np.ndarray:
    cx, cy, w, h = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3]
    return np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], 1)


def decode_yolov5(out: np.ndarray, layout: ModelLayout) -> tuple[np.ndarray, np.ndarray]:
    rows = out[0]
    scores = rows[:, 4] * rows[:, 5 + layout.person_class]
    keep = scores > 1e-3
    return _cxcywh(rows[keep]).astype(np.float32), scores[keep].astype(np.float32)


def decode_yolov8(out: np.ndarray, layout: ModelLayout) -> tuple[np.ndarray, np.ndarray]:
    cols = out[0]  # (4 + C, N)
    scores = cols[4 + layout.person_class]
    keep = scores > 1e-3
    return _cxcywh(cols[:4, keep].T).astype(np.float32), scores[keep].astype(np.float32)


def decode_end2end(out: np.ndarray, layout: ModelLayout) -> tuple[np.ndarray, np.ndarray]:
    rows = out[0]
    keep = (np.rint(rows[:, 5]) == layout.person_class) & (rows[:, 4] > 1e-3)
    return rows[keep, :4].astype(np.float32), rows[keep, 4].astype(np.float32)


def decode_yolox(out: np.ndarray, layout: ModelLayout) -> tuple[np.ndarray, np.ndarray]:
    rows = out[0]
    grids, strides = [], []
    for s in layout.strides:
        gh, gw = layout.input_height // s, layout.input_width // s
        yy, xx = np.mgrid[0:gh, 0:gw]
        grids.append(np.stack([xx.ravel(), yy.ravel()], 1))
        strides.append(np.full(gh * gw, s))
    grid = np.concatenate(grids).astype(np.float32)
    stride = np.concatenate(strides).astype(np.float32)[:, None]
    scores = rows[:, 4] * rows[:, 5 + layout.person_class]
    keep = scores > 1e-3
    r = rows[keep]
    xy = (r[:, :2] + grid[keep]) * stride[keep]
    wh = np.exp(r[:, 2:4]) * stride[keep]
    return _cxcywh(np.concatenate([xy, wh], 1)).astype(np.float32), scores[keep].astype(np.float32)


def decode_zoo(outputs: list[np.ndarray], layout: ModelLayout) -> tuple[np.ndarray, np.ndarray]:
    """ONNX Model Zoo tiny-yolov3: boxes (1,N,4) y1 x1 y2 x2 in frame pixels, scores (1,C,N),
    selected indices (K,3) or (1,K,3) of (batch, class, box)."""
    boxes, scores, indices = outputs
    idx = indices.reshape(-1, 3).astype(np.int64)
    idx = idx[(idx[:, 0] >= 0) & (idx[:, 1] == layout.person_class)]
    b = boxes[0, idx[:, 2]][:, [1, 0, 3, 2]]
    s = scores[0, idx[:, 1], idx[:, 2]]
    return b.astype(np.float32), s.astype(np.float32)


# ----------------------------------------------------------------------------- model loading


def _meta(session) -> dict[str, str]:
    return dict(session.get_modelmeta().custom_metadata_map or {})


def _parse_names(raw: str | None) -> dict[int, str]:
    if not raw:
        return {}
    try:
        data = json.loads(raw)
    except ValueError:
        try:  # ultralytics writes a Python dict literal
            import ast

            data = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            return {}
    if isinstance(data, list):
        return dict(enumerate(map(str, data)))
    if isinstance(data, dict):
        return {int(k): str(v) for k, v in data.items()}
    return {}


def _dim(d, default: int) -> int:
    return d if isinstance(d, int) and d > 0 else default


def inspect_model(session, config: DetectorConfig) -> ModelLayout:
    """Find the layout of a loaded model from its shapes and metadata; ModelError otherwise."""
    inputs, outputs = session.get_inputs(), session.get_outputs()
    meta = _meta(session)
    names = _parse_names(meta.get("names"))
    in_names = [i.name for i in inputs]
    shapes = [tuple(o.shape) for o in outputs]
    found = f"inputs {[(i.name, tuple(i.shape)) for i in inputs]}, outputs {shapes}"
    person = next((k for k, v in names.items() if v == "person"), 0)

    if "image_shape" in in_names and len(outputs) == 3:  # ONNX Model Zoo tiny-yolov3
        image = next(i for i in inputs if i.name != "image_shape")
        size = config.input_size
        return ModelLayout("zoo", image.name, _dim(image.shape[3], size),
                           _dim(image.shape[2], size), pad_value=128,
                           names=names or {0: "person"}, person_class=person)

    image = inputs[0]
    shp = list(image.shape)
    if len(shp) != 4:
        raise ModelError(f"model input {image.name} has shape {tuple(shp)}; expected 4-D image")
    nhwc = shp[3] == 3 and shp[1] != 3
    ih = _dim(shp[1] if nhwc else shp[2], config.input_size)
    iw = _dim(shp[2] if nhwc else shp[3], config.input_size)
    imgsz = meta.get("imgsz")
    if imgsz and not (isinstance(shp[2], int) and shp[2] > 0):
        with contextlib.suppress(ValueError):
            ih, iw = (list(_parse_list(imgsz)) * 2)[:2]
    base = dict(input_name=image.name, input_width=iw, input_height=ih, input_nhwc=nhwc,
                names=names, person_class=person)
    kind = config.layout or meta.get("layout")
    if kind is not None and kind not in LAYOUTS:
        raise ModelError(f"unknown layout {kind!r}; known: {', '.join(LAYOUTS)}")

    if kind == "darknet" or (kind is None and len(outputs) in (2, 3)
                             and all(len(s) == 4 for s in shapes)):
        return _darknet_layout(shapes, meta, config, base, found)
    if len(outputs) != 1 or len(shapes[0]) != 3:
        raise ModelError(f"no known output layout: {found}")
    _, d1, d2 = shapes[0]
    d1 = d1 if isinstance(d1, int) else -1
    d2 = d2 if isinstance(d2, int) else -1
    cells = sum((ih // s) * (iw // s) for s in (8, 16, 32))
    if kind is None:
        if d2 == 6:
            kind = "end2end"
        elif 0 < d1 < d2:
            kind = "yolov8"
        elif d2 > 5 and d1 == cells:
            kind = "yolox"
        elif d2 > 5:
            kind = "yolov5"
        else:
            raise ModelError(f"no known output layout: {found}")
    nc = {"yolov8": d1 - 4, "yolov5": d2 - 5, "yolox": d2 - 5}.get(kind, len(names) or 80)
    if kind == "yolox":
        return ModelLayout(kind, rgb=False, scale=1.0, pad_value=114, centered=False,
                           num_classes=nc, **base)
    return ModelLayout(kind, num_classes=nc, **base)


def _parse_list(raw: str) -> list[int]:
    return [int(v) for v in raw.strip("[]() ").replace(",", " ").split()]


def _darknet_layout(shapes, meta, config: DetectorConfig, base: dict, found: str) -> ModelLayout:
    if not all(len(s) == 4 and all(isinstance(d, int) and d > 0 for d in s[1:]) for s in shapes):
        raise ModelError(f"no known output layout (darknet heads need static shapes): {found}")
    nhwc = all(s[1] == s[2] and s[3] % 3 == 0 and s[3] != s[1] for s in shapes)
    nchw = all(s[2] == s[3] and s[1] % 3 == 0 for s in shapes)
    if not (nchw or nhwc):
        raise ModelError(f"no known output layout: {found}")
    channels = shapes[0][3] if nhwc and not nchw else shapes[0][1]
    anchors = config.anchors or _json(meta.get("anchors"))
    masks = config.masks or _json(meta.get("masks"))
    n_heads = len(shapes)
    if anchors is None:
        anchors = TINY_ANCHORS if n_heads == 2 else V3_ANCHORS
    if masks is None:
        masks = TINY_MASKS if n_heads == 2 else V3_MASKS
    if len(masks) != n_heads:
        raise ModelError(f"{len(masks)} anchor masks for {n_heads} output heads")
    per_anchor = channels // len(masks[0])
    nc = per_anchor - 5
    if nc < 1 or per_anchor * len(masks[0]) != channels:
        raise ModelError(f"no known output layout: {channels} channels per head in {found}")
    return ModelLayout("darknet", pad_value=128, num_classes=nc,
                       anchors=tuple(tuple(a) for a in anchors),
                       masks=tuple(tuple(m) for m in masks), heads_nhwc=nhwc and not nchw, **base)


def _json(raw: str | None):
    if not raw:
        return None
    try:
        return json.loads(raw)
    except ValueError:
        return None


def open_session(model_path: str | Path, threads: int, spin_wait: bool = False):
    """An onnxruntime CPU session with full graph optimisation; ModelError on a bad file."""
    import onnxruntime as ort

    path = Path(model_path)
    if not path.is_file():
        raise ModelError(f"model file not found: {path}")
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.intra_op_num_threads = max(1, threads)
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if spin_wait else "0")
    try:
        return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types for corrupt files
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ModelError(f"cannot load model {path}: {first[:200]}") from None


class Detector:
    """Loads a model once, warms it up, and turns BGR frames into ``Persons``."""

    def __init__(self, model_path: str | Path, config: DetectorConfig | None = None) -> None:
        self.config = config or DetectorConfig()
        self.model_path = Path(model_path)
        self.session = open_session(model_path, self.config.threads, self.config.spin_wait)
        self.layout = inspect_model(self.session, self.config)
        self.output_names = [o.name for o in self.session.get_outputs()]
        self._letterbox = Letterboxer(self.layout)
        self._batch_letterbox: list[Letterboxer] = []  # detect_batch: one per batch slot
        # Warm-up: the first run allocates; do it now, not on the first real frame.
        self.detect(np.full((self.layout.input_height, self.layout.input_width, 3), 114, np.uint8))

    def finest_stride_px(self) -> float:
        """Input pixels per cell of the finest output grid (16 for tiny-YOLOv3 at 416)."""
        if self.layout.kind == "darknet":
            grids = [o.shape[1] if self.layout.heads_nhwc else o.shape[2]
                     for o in self.session.get_outputs()]
            return self.layout.input_height / max(grids)
        return float(min(self.layout.strides))

    def foot_uncertainty_px(self, frame_width: int, frame_height: int) -> float:
        """``foot_uncertainty_cells`` finest-grid cells in frame pixels of this frame size."""
        scale = min(self.layout.input_width / frame_width, self.layout.input_height / frame_height)
        return self.config.foot_uncertainty_cells * self.finest_stride_px() / scale

    def run_raw(self, tensor: np.ndarray, frame_hw: tuple[int, int]) -> list[np.ndarray]:
        feeds = {self.layout.input_name: tensor}
        if self.layout.kind == "zoo":
            feeds["image_shape"] = np.array([frame_hw], np.float32)
        return self.session.run(self.output_names, feeds)

    def detect_timed(self, image_bgr: np.ndarray, frame: FrameInfo | None = None) -> Detection:
        if image_bgr is None or image_bgr.ndim != 3 or image_bgr.shape[2] != 3:
            raise InputError("frame is not a BGR image")
        t0 = time.perf_counter()
        tensor, box = self._letterbox(image_bgr)
        t1 = time.perf_counter()
        outputs = self.run_raw(tensor, image_bgr.shape[:2])
        t2 = time.perf_counter()
        persons, candidates, overflow = self.postprocess(outputs, box, image_bgr.shape[:2], frame)
        t3 = time.perf_counter()
        return Detection(persons, (t1 - t0) * 1e3, (t2 - t1) * 1e3, (t3 - t2) * 1e3,
                         candidates, overflow)

    def detect(self, image_bgr: np.ndarray, frame: FrameInfo | None = None) -> Persons:
        return self.detect_timed(image_bgr, frame).persons

    @property
    def batchable(self) -> bool:
        """The model's batch dimension is dynamic: several frames can run as one batch."""
        first = self.session.get_inputs()[0].shape[0]
        return self.layout.kind != "zoo" and not (isinstance(first, int) and first > 0)

    def detect_batch_timed(self, images: list[np.ndarray],
                           frames: list[FrameInfo | None] | None = None) -> list[Detection]:
        """Detect in frames that are ready together (e.g. one per camera) as one inference
        when the model has a dynamic batch dimension, else one after the other. The result for
        each frame is the same as ``detect_timed``'s; inference time is shared equally."""
        frames = list(frames) if frames is not None else [None] * len(images)
        if len(frames) != len(images):
            raise InputError(f"{len(images)} images but {len(frames)} frame infos")
        if len(images) <= 1 or not self.batchable:
            return [self.detect_timed(im, fr) for im, fr in zip(images, frames, strict=True)]
        for im in images:
            if im is None or im.ndim != 3 or im.shape[2] != 3:
                raise InputError("frame is not a BGR image")
        t0 = time.perf_counter()
        while len(self._batch_letterbox) < len(images):  # one canvas per batch slot
            self._batch_letterbox.append(Letterboxer(self.layout))
        prepared = [lb(im) for lb, im in zip(self._batch_letterbox, images, strict=False)]
        tensor = np.concatenate([t for t, _ in prepared])
        t1 = time.perf_counter()
        outputs = self.session.run(self.output_names, {self.layout.input_name: tensor})
        t2 = time.perf_counter()
        share = (t2 - t1) * 1e3 / len(images)
        pre = (t1 - t0) * 1e3 / len(images)
        result = []
        for i, (im, fr) in enumerate(zip(images, frames, strict=True)):
            t3 = time.perf_counter()
            persons, candidates, overflow = self.postprocess(
                [o[i:i + 1] for o in outputs], prepared[i][1], im.shape[:2], fr)
            result.append(Detection(persons, pre, share, (time.perf_counter() - t3) * 1e3,
                                    candidates, overflow))
        return result

    def detect_batch(self, images: list[np.ndarray],
                     frames: list[FrameInfo | None] | None = None) -> list[Persons]:
        """Persons per frame (see ``detect_batch_timed``)."""
        return [d.persons for d in self.detect_batch_timed(images, frames)]

    def postprocess(self, outputs: list[np.ndarray], box: Letterbox, frame_hw: tuple[int, int],
                    frame: FrameInfo | None) -> tuple[Persons, int, bool]:
        """Decode, threshold, cap, NMS, merge, undo the letterbox. Pure given the outputs."""
        cfg, layout = self.config, self.layout
        boxes, scores = decode(outputs, layout)
        keep = scores >= cfg.score_threshold
        boxes, scores = boxes[keep], scores[keep]
        candidates = len(scores)
        overflow = candidates > cfg.top_k
        if overflow:
            top = np.argpartition(-scores, cfg.top_k)[:cfg.top_k]
            boxes, scores = boxes[top], scores[top]
        kept = box_ops.nms(boxes, scores, cfg.nms_iou)
        boxes, scores = box_ops.merge_boxes(boxes[kept], scores[kept], cfg.merge_iou,
                                            cfg.merge_ios, cfg.merge_touch_px)
        if layout.kind != "zoo":  # the zoo graph undoes its letterbox itself
            boxes = box.to_frame(boxes)
        h, w = frame_hw
        boxes = np.clip(boxes, 0, [w, h, w, h]).astype(np.float32)
        return Persons(boxes, scores, frame), candidates, overflow


def decode(outputs: list[np.ndarray], layout: ModelLayout) -> tuple[np.ndarray, np.ndarray]:
    """Dispatch to the decoder of ``layout.kind``: person boxes in input pixels and scores."""
    if layout.kind == "darknet":
        return decode_darknet(outputs, layout)
    if layout.kind == "zoo":
        return decode_zoo(outputs, layout)
    decoder = {"yolov5": decode_yolov5, "yolov8": decode_yolov8, "end2end": decode_end2end,
               "yolox": decode_yolox}[layout.kind]
    return decoder(outputs[0], layout)


def describe(detector: Detector) -> dict:
    """What `monitor model info` prints."""
    import onnx

    layout = detector.layout
    try:
        model = onnx.load(str(detector.model_path), load_external_data=False)
        params = int(sum(np.prod(t.dims) for t in model.graph.initializer))
    except Exception:  # info is best effort; the session already loaded the model
        params = -1
    return {
        "model": str(detector.model_path),
        "layout": layout.kind,
        "input": f"{layout.input_width}x{layout.input_height}",
        "input_order": ("NHWC" if layout.input_nhwc else "NCHW")
        + (" RGB" if layout.rgb else " BGR"),
        "classes": layout.num_classes,
        "person_class": layout.person_class,
        "parameters": params,
        "outputs": [f"{o.name} {tuple(o.shape)}" for o in detector.session.get_outputs()],
        "anchors": list(layout.anchors) if layout.anchors else None,
        "masks": list(layout.masks) if layout.masks else None,
    }
