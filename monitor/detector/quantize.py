"""Static int8 quantization of a detector model, calibrated on the user's own frames.

Why static int8: on the CPUs this monitor runs on, onnxruntime's QDQ int8 convolutions run a
tiny-YOLO 2.4-2.6x faster than fp32, while dynamic quantization is slower than fp32 and fp16
gains nothing. Static quantization needs the range of every activation, measured by running the
model on calibration frames: those must look like the cell (same cameras, light, clothing), so
they are the user's own frames, letterboxed exactly as the detector does.

The int8 model is then checked against the fp32 model on frames *not* used for calibration:
persons found by both, by one only, how well their boxes agree (IoU), and the speed of each.
Below the agreement threshold the model is not written (unless forced): a person the fp32 model
sees and the int8 model misses is a missed STOP.

Choices (measured; see docs/models-int8.md): QDQ format, uint8 activations, int8 per-channel
weights, MinMax calibration, and the output heads kept in float (the last convolution of each
head and everything after it: box sizes and scores need more than 256 levels).
"""

from __future__ import annotations

import logging
import statistics
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from monitor.errors import InputError, ModelError, MonitorError

METHODS = ("minmax", "entropy", "percentile")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
# Ops that compute a weighted sum: walking back from a model output, the first of these on each
# path is the head's last layer; it and everything after it stay in float.
_WEIGHTED = {"Conv", "ConvTranspose", "MatMul", "Gemm"}
MIN_FRAMES = 8


class QuantizeRefused(MonitorError):
    """The int8 model disagrees with the fp32 model on held-out frames; nothing was written."""


@dataclass(frozen=True)
class QuantizeOptions:
    """How to quantize. ``keep_float``: node names left in float; None = the output heads."""

    method: str = "minmax"
    keep_float: tuple[str, ...] | None = None
    # tensor name -> (scale, zero_point) of its uint8 activation, set instead of calibrated
    # (the synthetic model's analytic ranges)
    ranges: dict[str, tuple[float, int]] = field(default_factory=dict)
    percentile: float = 99.999
    # 7-bit weights: x86 CPUs without VNNI multiply uint8 activations by int8 weights with an
    # instruction that saturates at 16 bits when two large products add up; with 7-bit weights
    # no sum can saturate (measured: 8-bit weights lost every person of a YOLOv8-shaped model)
    reduce_range: bool = True

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise MonitorError(f"calibration method {self.method!r}: use one of "
                               f"{', '.join(METHODS)}")


@dataclass(frozen=True)
class Agreement:
    """fp32 against int8 on held-out frames (persons matched one to one at IoU >= 0.5)."""

    frames: int
    fp32_persons: int
    int8_persons: int
    both: int
    mean_iou: float
    min_iou: float
    fp32_ms: float  # median inference time per frame
    int8_ms: float

    @property
    def fp32_only(self) -> int:
        """Persons the int8 model misses: missed STOPs."""
        return self.fp32_persons - self.both

    @property
    def int8_only(self) -> int:
        """Persons only the int8 model sees: false STOPs."""
        return self.int8_persons - self.both

    @property
    def recall(self) -> float:
        return self.both / self.fp32_persons if self.fp32_persons else 1.0

    @property
    def precision(self) -> float:
        return self.both / self.int8_persons if self.int8_persons else 1.0

    @property
    def agreement(self) -> float:
        """Persons found by both over persons found by either."""
        either = self.fp32_persons + self.int8_persons - self.both
        return self.both / either if either else 1.0

    @property
    def speedup(self) -> float:
        return self.fp32_ms / self.int8_ms if self.int8_ms > 0 else float("nan")

    def table(self) -> str:
        rows = [
            ("held-out frames", f"{self.frames}"),
            ("persons (fp32 / int8)", f"{self.fp32_persons} / {self.int8_persons}"),
            ("found by both", f"{self.both}"),
            ("fp32 only (int8 misses)", f"{self.fp32_only}"),
            ("int8 only (false STOPs)", f"{self.int8_only}"),
            ("agreement", f"{self.agreement:.3f}"),
            ("recall / precision vs fp32", f"{self.recall:.3f} / {self.precision:.3f}"),
            ("box IoU mean / min", f"{self.mean_iou:.3f} / {self.min_iou:.3f}"),
            ("inference ms fp32 / int8", f"{self.fp32_ms:.1f} / {self.int8_ms:.1f} "
                                         f"({self.speedup:.2f}x)"),
        ]
        width = max(len(k) for k, _ in rows)
        return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


# ----------------------------------------------------------------------------- frames


def read_frames(source: str | Path, limit: int = 120) -> list[np.ndarray]:
    """BGR frames from a directory of images (sorted by name) or a video file, at most
    ``limit``, spread evenly over the video. InputError when none can be read."""
    source = Path(source)
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise InputError(f"no frames in {source}: expected images "
                             f"({', '.join(IMAGE_SUFFIXES)})")
        step = max(1, len(files) // limit)
        frames = []
        for path in files[::step][:limit]:
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if image is None:
                raise InputError(f"cannot read image {path}")
            frames.append(image)
        return frames
    if not source.is_file():
        raise InputError(f"frames not found: {source} (give a directory of images or a video)")
    cap = cv2.VideoCapture(str(source))
    try:
        if not cap.isOpened():
            raise InputError(f"cannot read video {source}")
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        step = max(1, count // limit) if count > 0 else 1
        frames, index = [], 0
        while len(frames) < limit:
            ok = cap.grab()
            if not ok:
                break
            if index % step == 0:
                ok, image = cap.retrieve()
                if ok and image is not None and image.ndim == 3:
                    frames.append(image)
            index += 1
    finally:
        cap.release()
    if not frames:
        raise InputError(f"cannot read video {source}: no frame decoded")
    return frames


def split_frames(frames: Sequence[np.ndarray], held_every: int = 4,
                 ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(calibration, held-out): every ``held_every``-th frame is held out for the check."""
    if len(frames) < MIN_FRAMES:
        raise InputError(f"only {len(frames)} frames: give at least {MIN_FRAMES} (most for "
                         "calibration, the rest to check the int8 model)")
    held = [f for i, f in enumerate(frames) if i % held_every == held_every - 1]
    calib = [f for i, f in enumerate(frames) if i % held_every != held_every - 1]
    return calib, held


# ----------------------------------------------------------------------------- quantization


def head_nodes(model) -> list[str]:
    """Names of the nodes from each output back to (and including) the last weighted layer."""
    producer = {out: node for node in model.graph.node for out in node.output}
    keep: list[str] = []
    seen: set[str] = set()
    stack = [o.name for o in model.graph.output]
    while stack:
        node = producer.get(stack.pop())
        if node is None or node.name in seen:
            continue
        seen.add(node.name)
        keep.append(node.name)
        if node.op_type not in _WEIGHTED:
            stack.extend(i for i in node.input if i)
    return keep


def _name_nodes(model) -> None:
    """The quantizer addresses nodes by name: give unnamed nodes stable ones."""
    used = {n.name for n in model.graph.node if n.name}
    for i, node in enumerate(model.graph.node):
        if not node.name:
            name = f"{node.op_type}_{i}"
            while name in used:
                name += "_"
            node.name = name
            used.add(name)


def calibration_feeds(detector, frames: Iterable[np.ndarray]) -> Iterator[dict[str, np.ndarray]]:
    """Model inputs for ``frames``, letterboxed by the detector's own preprocessing."""
    from monitor.detector import letterbox

    for image in frames:
        tensor, _ = letterbox(image, detector.layout)
        feeds = {detector.layout.input_name: np.ascontiguousarray(tensor)}
        if detector.layout.kind == "zoo":
            feeds["image_shape"] = np.array([image.shape[:2]], np.float32)
        yield feeds


def quantize_model(model_path: str | Path, out_path: str | Path,
                   calibration: Sequence[np.ndarray], options: QuantizeOptions | None = None,
                   wrap: Callable[[Iterable, int, str], Iterable] | None = None) -> Path:
    """Write the static int8 (QDQ) model of ``model_path`` to ``out_path``.

    ``calibration`` are BGR frames; ``wrap(iterable, total, desc)`` may show progress.
    """
    from onnxruntime.quantization import CalibrationDataReader, CalibrationMethod

    from monitor.detector import Detector, DetectorConfig

    options = options or QuantizeOptions()
    if not calibration:
        raise InputError("no calibration frames")
    detector = Detector(model_path, DetectorConfig(threads=1))
    feeds = list(calibration_feeds(detector, calibration))
    if wrap is not None:
        feeds_iter: Iterable = wrap(feeds, len(feeds), "calibrating")
    else:
        feeds_iter = feeds

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self._it = iter(feeds_iter)

        def get_next(self):
            return next(self._it, None)

    method = {"minmax": CalibrationMethod.MinMax, "entropy": CalibrationMethod.Entropy,
              "percentile": CalibrationMethod.Percentile}[options.method]
    out_path = Path(out_path)
    root = logging.getLogger()
    level = root.level
    root.setLevel(logging.ERROR)  # the quantizer logs advice on the root logger
    try:
        _quantize(model_path, out_path, Reader(), method, options)
    finally:
        root.setLevel(level)
    return out_path


def _quantize(model_path, out_path: Path, reader, method, options: QuantizeOptions) -> None:
    import onnx
    from onnxruntime.quantization import QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    with tempfile.TemporaryDirectory(prefix="monitor-quantize-") as tmp:
        try:
            model = onnx.load(str(model_path))
        except Exception as exc:
            raise ModelError(f"cannot read model {model_path}: {str(exc)[:200]}") from None
        _name_nodes(model)
        named = Path(tmp) / "named.onnx"
        onnx.save(model, str(named))
        pre = Path(tmp) / "pre.onnx"
        try:  # fold, fuse and infer shapes first: the quantizer then sees the final graph
            quant_pre_process(str(named), str(pre), skip_symbolic_shape=True)
            source = pre
        except Exception:  # some exports fail shape inference; the plain graph still works
            source = named
        keep = list(options.keep_float) if options.keep_float is not None \
            else head_nodes(onnx.load(str(source), load_external_data=False))
        overrides = {name: [{"scale": np.array(scale, np.float32),
                                  "zero_point": np.array(zp, np.uint8)}]
                     for name, (scale, zp) in options.ranges.items()}
        extra = {"TensorQuantOverrides": overrides} if overrides else {}
        if options.method == "percentile":
            extra["CalibPercentile"] = options.percentile
        result = Path(tmp) / "int8.onnx"
        try:
            quantize_static(str(source), str(result), reader, quant_format=QuantFormat.QDQ,
                            per_channel=True, activation_type=QuantType.QUInt8,
                            weight_type=QuantType.QInt8, reduce_range=options.reduce_range,
                            calibrate_method=method,
                            nodes_to_exclude=keep, extra_options=extra)
        except MonitorError:
            raise
        except Exception as exc:
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise ModelError(f"cannot quantize {model_path}: {first[:200]}") from None
        out_path.parent.mkdir(parents=True, exist_ok=True)
        staged = out_path.with_name(out_path.name + ".tmp")
        staged.write_bytes(result.read_bytes())
        staged.replace(out_path)


# ----------------------------------------------------------------------------- comparison


def _iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = np.asarray(a, float).reshape(-1, 4), np.asarray(b, float).reshape(-1, 4)
    x1 = np.maximum(a[:, None, 0], b[None, :, 0])
    y1 = np.maximum(a[:, None, 1], b[None, :, 1])
    x2 = np.minimum(a[:, None, 2], b[None, :, 2])
    y2 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1), 0.0)


def match_persons(a: np.ndarray, b: np.ndarray, min_iou: float = 0.5) -> list[float]:
    """IoUs of the one-to-one matches between two box sets (greedy, best IoU first)."""
    iou = _iou_matrix(a, b)
    matches: list[float] = []
    while iou.size and iou.max() >= min_iou:
        i, j = np.unravel_index(int(np.argmax(iou)), iou.shape)
        matches.append(float(iou[i, j]))
        iou[i, :] = -1.0
        iou[:, j] = -1.0
    return matches


def compare(fp32, int8, frames: Iterable[np.ndarray], min_iou: float = 0.5,
            wrap: Callable[[Iterable, int, str], Iterable] | None = None) -> Agreement:
    """Run both detectors on ``frames`` and count the persons they agree on. ``fp32`` (the
    reference) may also be its detections on ``frames``, already run (``detect_all``)."""
    frames = list(frames)
    items: Iterable = wrap(frames, len(frames), "comparing") if wrap else frames
    given = fp32 if isinstance(fp32, list) else None
    ra, rb = [], []
    for k, image in enumerate(items):
        ra.append(given[k] if given is not None else fp32.detect_timed(image))
        rb.append(int8.detect_timed(image))
    return agreement_of(ra, rb, min_iou)


def detect_all(detector, frames: Iterable[np.ndarray]) -> list:
    """The detector's ``Detection`` on each frame (a reference compared with several)."""
    return [detector.detect_timed(image) for image in frames]


def agreement_of(reference: Sequence, other: Sequence, min_iou: float = 0.5) -> Agreement:
    """Count the persons two runs (``Detection`` per frame, in the same order) agree on."""
    n_a = n_b = both = 0
    ious: list[float] = []
    for ra, rb in zip(reference, other, strict=True):
        matched = match_persons(ra.persons.boxes_px, rb.persons.boxes_px, min_iou)
        n_a += len(ra.persons)
        n_b += len(rb.persons)
        both += len(matched)
        ious += matched
    ms_a = [r.inference_ms for r in reference]
    ms_b = [r.inference_ms for r in other]
    return Agreement(len(reference), n_a, n_b, both, float(np.mean(ious)) if ious else 0.0,
                     min(ious) if ious else 0.0,
                     statistics.median(ms_a) if ms_a else 0.0,
                     statistics.median(ms_b) if ms_b else 0.0)


def check_agreement(agreement: Agreement, min_agreement: float) -> str | None:
    """Why the int8 model must not be used, or None."""
    if agreement.fp32_persons == 0:
        return ("the fp32 model finds no person in the held-out frames, so the int8 model "
                "cannot be checked: give frames with persons in the cell")
    if agreement.agreement < min_agreement:
        return (f"int8 agrees with fp32 on {agreement.agreement:.3f} of the persons "
                f"(below {min_agreement}): {agreement.fp32_only} missed, "
                f"{agreement.int8_only} extra on {agreement.frames} held-out frames")
    return None


def default_output(model_path: Path) -> Path:
    """``m.onnx`` -> ``m.int8.onnx`` beside it."""
    return model_path.with_name(model_path.stem + ".int8.onnx")
