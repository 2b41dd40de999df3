"""Person detector: any tiny-YOLO style ONNX model, run by onnxruntime or OpenVINO.

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
score threshold, a top-k cap, NMS and merging (``monitor.geometry.boxes``). NaN or infinite outputs
raise ``DetectorError`` (never "no persons"); ``Detector.self_test`` checks the model still
finds a known person. Modules: layouts (which layout, person classes), preprocess (letterbox),
decode, runners (the backend seam: "run this model on this tensor" for onnxruntime and OpenVINO),
choice (which backend and precision runs, by measurement, gated by agreement), selftest, config.

Also here: cheap statistics of a small grey image that the envelope and the camera checks are judged
by (``imagestats.py``) and static int8 quantization calibrated on the user's frames
(``quantize.py``). May import: ``monitor.frames``, ``monitor.scene`` (the self-test's figure),
``monitor.geometry`` (box algebra) and the bottom layer; never the pipeline.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from monitor.detector.config import DetectorConfig
from monitor.detector.decode import (
    check_finite,
    decode,
    decode_darknet,
    decode_end2end,
    decode_yolov5,
    decode_yolov8,
    decode_yolox,
    decode_zoo,
)
from monitor.detector.layouts import (
    LAYOUTS,
    TINY_ANCHORS,
    TINY_MASKS,
    V3_ANCHORS,
    V3_MASKS,
    ModelLayout,
    inspect_model,
)
from monitor.detector.preprocess import Letterbox, Letterboxer, fitted_input, letterbox
from monitor.detector.runners import (
    REFERENCE,
    BackendUnavailable,
    Candidate,
    Runner,
    open_runner,
)
from monitor.detector.selftest import SelfTestCase, builtin_case, load_case
from monitor.detector.selftest import check as check_self_test
from monitor.detector.shapes import OutputShapes
from monitor.detector.test_model import TEST_MODEL_NOTE
from monitor.errors import DetectorError, InputError
from monitor.geometry import boxes as box_ops
from monitor.types import Fault, FrameInfo, Persons

__all__ = [
    "LAYOUTS", "TINY_ANCHORS", "TINY_MASKS", "V3_ANCHORS", "V3_MASKS", "BackendUnavailable",
    "Candidate", "Detection", "Detector", "DetectorConfig", "DetectorError", "Letterbox",
    "Letterboxer", "ModelLayout", "Runner", "configured_candidate", "decode", "decode_darknet",
    "decode_end2end", "decode_yolov5", "decode_yolov8", "decode_yolox", "decode_zoo",
    "describe", "inspect_model", "letterbox", "open_runner",
]

log = logging.getLogger(__name__)
# Decides per raw box (x1 y1 x2 y2, frame pixels) whether it is kept: True = keep.
PreMerge = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Detection:
    """One detect call: the persons, stage times (ms) and whether candidates were capped."""

    persons: Persons
    preprocess_ms: float
    inference_ms: float
    decode_ms: float
    candidates: int
    overflow: bool


class Detector:
    """Loads a model once, warms it up, and turns BGR frames into ``Persons``."""

    def __init__(self, model_path: str | Path, config: DetectorConfig | None = None,
                 runner: Runner | None = None) -> None:
        """``runner``: the backend to run the model with (``monitor.detector.choice`` picks
        one by measurement); None: the backend the config names, onnxruntime on the CPU for
        ``backend = "auto"`` (the choice is made by whoever opens the detector with
        ``choice.open_detector``)."""
        self.config = config or DetectorConfig()
        self.model_path = Path(model_path)
        self.runner = runner or open_runner(model_path, configured_candidate(self.config),
                                            self.config.threads, self.config.spin_wait)
        self.layout, self.warning = inspect_model(self.runner, self.config)
        if self.warning:
            log.warning("%s: %s", self.model_path.name, self.warning)
        self.output_names = [o.name for o in self.runner.outputs]
        # the synthetic model: finds only the magenta test figures of monitor.scene, never a
        # real person (see monitor/detector/test_model.py)
        meta = self.runner.metadata
        self.test_model = "synthetic_weights" in meta
        self._letterbox = Letterboxer(self.layout)
        self.self_test_case = self._self_test_case()
        self._self_test_letterbox: Letterboxer | None = None
        self._batch_letterbox: list[Letterboxer] = []  # detect_batch: one canvas per slot
        # output shapes per input size: found by the warm-up at the full input, derived from
        # those for the other sizes of a rectangular input (layout.rect: one per frame shape)
        self._shapes: dict[tuple[int, int], OutputShapes] = {}
        self._layouts: dict[tuple[int, int], ModelLayout] = {}
        # Warm-up: the first run allocates; do it now, not on the first real frame.
        self.detect(np.full((self.layout.input_height, self.layout.input_width, 3), 114, np.uint8))
        self.output_shapes = self._shapes[(self.layout.input_width, self.layout.input_height)]
        if self.layout.rect:
            self._try_rectangular_input()

    def _try_rectangular_input(self) -> None:
        """A model that declares a dynamic input size but cannot run at a smaller input, or
        whose outputs do not follow it (a fixed reshape inside), runs every frame in the full
        square, as it did in the warm-up, with a warning."""
        layout = self.layout
        probe = np.full((layout.input_height // 2, layout.input_width, 3), 114, np.uint8)
        try:
            self.detect(probe)
            return
        except Exception as exc:  # the runtime's own errors, or DetectorError from the shapes
            why = str(exc).splitlines()[0][:200]
        log.warning("%s: declares a dynamic input size but fails at a smaller one (%s): every "
                    "frame runs in the full %dx%d input", self.model_path.name, why,
                    layout.input_width, layout.input_height)
        self.layout = replace(layout, rect=False)
        self._letterbox = Letterboxer(self.layout)
        full = (layout.input_width, layout.input_height)
        self._shapes = {full: self.output_shapes}
        self._layouts = {}

    def _self_test_case(self) -> SelfTestCase | None:
        cfg = self.config
        if cfg.self_test_image is not None and cfg.self_test_box is not None:
            return load_case(cfg.self_test_image, cfg.self_test_box)
        if "synthetic_weights" in self.runner.metadata:  # ours: it finds the scene's persons
            return builtin_case()
        log.info("%s: no detector self-test (set detector.self_test_image and self_test_box; "
                 "see docs/models.md)", self.model_path.name)
        return None

    @property
    def backend(self) -> Candidate:
        """The backend and precision that run the model."""
        return self.runner.candidate

    def self_test(self) -> Fault | None:
        """Run the model on the self-test image: None if it finds the known person, else a
        STOP fault ``detector_self_test``. Also None when there is no self-test image for this
        model (see ``self_test_case``; docs/models.md).

        It has its own input buffer, so a self-test from another thread never overwrites the
        tensor of a frame being detected."""
        if self.self_test_case is None:
            return None
        if self._self_test_letterbox is None:
            self._self_test_letterbox = Letterboxer(self.layout)
        letterboxer = self._self_test_letterbox

        def detect(image: np.ndarray) -> Persons:
            tensor, box = letterboxer(image)
            outputs = self.run_raw(tensor, image.shape[:2], box)
            return self.postprocess(outputs, box, image.shape[:2], None)[0]

        return check_self_test(self.self_test_case, detect, self.config.self_test_min_iou)

    def finest_stride_px(self) -> float:
        """Input pixels per cell of the finest output grid (16 for tiny-YOLOv3 at 416)."""
        if self.layout.kind == "darknet":
            grids = [s[1] if self.layout.heads_nhwc else s[2] for s in self.output_shapes.shapes]
            return self.layout.input_height / max(grids)
        return float(min(self.layout.strides))

    def foot_uncertainty_px(self, frame_width: int, frame_height: int) -> float:
        """``foot_uncertainty_cells`` finest-grid cells in frame pixels of this frame size."""
        scale = min(self.layout.input_width / frame_width, self.layout.input_height / frame_height)
        return self.config.foot_uncertainty_cells * self.finest_stride_px() / scale

    def run_raw(self, tensor: np.ndarray, frame_hw: tuple[int, int],
                box: Letterbox) -> list[np.ndarray]:
        feeds = {self.layout.input_name: tensor}
        if self.layout.kind == "zoo":
            feeds["image_shape"] = np.array([frame_hw], np.float32)
        outputs = self.runner.run(feeds)
        self._check_shapes(outputs, 1, box)
        return outputs

    def _check_shapes(self, outputs: list[np.ndarray], batch: int, box: Letterbox) -> None:
        """Every run's outputs in the shapes of the warm-up run, scaled to this run's input
        size (monitor.detector.shapes)."""
        size = (box.input_width, box.input_height)
        found = self._shapes.get(size)
        if found is None:
            if not self._shapes:  # the warm-up, at the full input
                found = OutputShapes.found(self.layout, self.output_names, outputs)
            else:
                load = self._shapes[(self.layout.input_width, self.layout.input_height)]
                found = load.at_input(self.layout, self._layout_at(box))
            self._shapes[size] = found
        found.check(outputs, batch)

    def _layout_at(self, box: Letterbox) -> ModelLayout:
        """The layout at the input size this frame ran at (decoding needs the grid strides)."""
        size = (box.input_width, box.input_height)
        layout = self._layouts.get(size)
        if layout is None:
            layout = self._layouts[size] = (
                self.layout if size == (self.layout.input_width, self.layout.input_height)
                else replace(self.layout, input_width=size[0], input_height=size[1]))
        return layout

    def detect_timed(self, image_bgr: np.ndarray, frame: FrameInfo | None = None,
                     pre_merge: PreMerge | None = None) -> Detection:
        """Detect persons; ``pre_merge(boxes_px) -> keep`` (frame pixels, one bool per raw box)
        drops raw boxes before the top-k cap, NMS and merging (masks, see monitor.pipeline)."""
        if image_bgr is None or image_bgr.ndim != 3 or image_bgr.shape[2] != 3:
            raise InputError("frame is not a BGR image")
        t0 = time.perf_counter()
        tensor, box = self._letterbox(image_bgr)
        t1 = time.perf_counter()
        outputs = self.run_raw(tensor, image_bgr.shape[:2], box)
        t2 = time.perf_counter()
        persons, candidates, overflow = self.postprocess(outputs, box, image_bgr.shape[:2], frame,
                                                         pre_merge)
        t3 = time.perf_counter()
        return Detection(persons, (t1 - t0) * 1e3, (t2 - t1) * 1e3, (t3 - t2) * 1e3,
                         candidates, overflow)

    def detect(self, image_bgr: np.ndarray, frame: FrameInfo | None = None) -> Persons:
        return self.detect_timed(image_bgr, frame).persons

    @property
    def batchable(self) -> bool:
        """The model's batch dimension is dynamic: several frames can run as one batch."""
        first = (self.runner.inputs[0].shape or (None,))[0]
        return self.layout.kind != "zoo" and first is None

    def detect_batch_timed(self, images: list[np.ndarray],
                           frames: list[FrameInfo | None] | None = None,
                           pre_merge: list[PreMerge | None] | None = None) -> list[Detection]:
        """Detect in frames that are ready together (e.g. one per camera) as one inference
        when the model has a dynamic batch dimension, else one after the other. The result for
        each frame is the same as ``detect_timed``'s; inference time is shared equally.
        ``pre_merge`` gives each frame's own pre-merge mask (its camera's mask zones)."""
        frames = list(frames) if frames is not None else [None] * len(images)
        masks = list(pre_merge) if pre_merge is not None else [None] * len(images)
        if not len(frames) == len(masks) == len(images):
            raise InputError(f"{len(images)} images but {len(frames)} frame infos and "
                             f"{len(masks)} pre-merge masks")
        if len(images) <= 1 or not self.batchable:
            return [self.detect_timed(im, fr, pm)
                    for im, fr, pm in zip(images, frames, masks, strict=True)]
        for im in images:
            if im is None or im.ndim != 3 or im.shape[2] != 3:
                raise InputError("frame is not a BGR image")
        t0 = time.perf_counter()
        while len(self._batch_letterbox) < len(images):
            self._batch_letterbox.append(Letterboxer(self.layout))
        prepared = [lb(im) for lb, im in zip(self._batch_letterbox, images, strict=False)]
        if len({t.shape for t, _ in prepared}) > 1:  # frames of other shapes: inputs differ
            return [self.detect_timed(im, fr, pm)
                    for im, fr, pm in zip(images, frames, masks, strict=True)]
        tensor = np.concatenate([t for t, _ in prepared])
        t1 = time.perf_counter()
        outputs = self.runner.run({self.layout.input_name: tensor})
        self._check_shapes(outputs, len(images), prepared[0][1])
        t2 = time.perf_counter()
        share = (t2 - t1) * 1e3 / len(images)
        pre = (t1 - t0) * 1e3 / len(images)
        result = []
        for i, (im, fr, pm) in enumerate(zip(images, frames, masks, strict=True)):
            t3 = time.perf_counter()
            persons, candidates, overflow = self.postprocess(
                [o[i:i + 1] for o in outputs], prepared[i][1], im.shape[:2], fr, pm)
            result.append(Detection(persons, pre, share, (time.perf_counter() - t3) * 1e3,
                                    candidates, overflow))
        return result

    def detect_batch(self, images: list[np.ndarray],
                     frames: list[FrameInfo | None] | None = None) -> list[Persons]:
        """Persons per frame (see ``detect_batch_timed``)."""
        return [d.persons for d in self.detect_batch_timed(images, frames)]

    def postprocess(self, outputs: list[np.ndarray], box: Letterbox, frame_hw: tuple[int, int],
                    frame: FrameInfo | None, pre_merge: PreMerge | None = None,
                    ) -> tuple[Persons, int, bool]:
        """Decode, threshold, pre-merge mask, cap, NMS, merge, undo the letterbox. Pure given
        the outputs."""
        cfg, layout = self.config, self._layout_at(box)
        check_finite(outputs, self.output_names)
        boxes, scores = decode(outputs, layout, cfg.score_threshold)
        keep = scores >= cfg.score_threshold
        boxes, scores = boxes[keep], scores[keep]
        if not np.isfinite(boxes).all():  # e.g. exp() of a huge size logit
            raise DetectorError(f"model gave {int((~np.isfinite(boxes)).any(axis=1).sum())} "
                                f"person boxes of infinite size: the model is broken")
        if pre_merge is not None and len(scores):
            in_frame = boxes if layout.kind == "zoo" else box.to_frame(boxes)
            keep = np.asarray(pre_merge(in_frame))
            if keep.dtype != bool or keep.shape != scores.shape:
                raise DetectorError(f"pre-merge mask has shape {keep.shape} and type "
                                    f"{keep.dtype}; expected {len(scores)} booleans")
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


def configured_candidate(config: DetectorConfig) -> Candidate:
    """The backend and precision the config names; ``auto`` is onnxruntime, the reference,
    at the model's own precision until a measurement chooses (``monitor.detector.choice``)."""
    backend = REFERENCE if config.backend == "auto" else config.backend
    return Candidate(backend, config.precision)


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
        **({"test_model": TEST_MODEL_NOTE} if detector.test_model else {}),
        "backend": detector.backend.label,
        "layout": layout.kind,
        "input": f"{layout.input_width}x{layout.input_height}" + (
            " (dynamic: each frame runs in the smallest rectangle that holds it, 16:9 at "
            f"{'x'.join(map(str, fitted_input(layout, 1280, 720)))})" if layout.rect else ""),
        "input_order": ("NHWC" if layout.input_nhwc else "NCHW")
        + (" RGB" if layout.rgb else " BGR"),
        "classes": layout.num_classes,
        "person_classes": ", ".join(f"{c} ({layout.names.get(c, '?')})"
                                    for c in layout.persons),
        "self_test": detector.self_test_case.source if detector.self_test_case
        else "none (set detector.self_test_image and self_test_box)",
        "parameters": params,
        "outputs": [f"{o.name} {tuple(o.shape)}" for o in detector.runner.outputs],
        "anchors": list(layout.anchors) if layout.anchors else None,
        "masks": list(layout.masks) if layout.masks else None,
    }
