"""The model's operating envelope: the image conditions within which it still finds a person.

The self-test says the model finds one person in one fixed image; it says nothing about
tonight's lighting. ``measure`` degrades the self-test image (the synthetic figure for the
synthetic model, the user's self-test image for theirs) in graded steps along four axes and
runs the detector on each grade:

==========  ====================================================  ==========================
axis        degradation                                           limit kept
==========  ====================================================  ==========================
brightness  every pixel times a gain (exposure, light off)        ``min_gain``, ``max_gain``
contrast    pixels pulled towards the image mean (haze, glare)    ``min_contrast``
noise       Gaussian noise per pixel and channel (grey levels)    ``max_noise``
blur        Gaussian blur (sigma in detector-input pixels)        ``max_blur``
glare       a clipped (255) band over this share of the figure    ``max_glare``
==========  ====================================================  ==========================

Each grade is ``TRIALS`` trials (the image shifted by fractions of the model's finest grid
cell, each with its own noise): recall = trials in which a person box covers the known one.
A limit is the last grade with recall >= ``min_recall`` before the first grade without,
found by bisection (recall falls as a condition worsens); an axis that passes every grade
ends at the last grade (beyond it nothing was measured, so it counts as outside).

Units are *degradations relative to an undegraded image*, not absolute pixel statistics:
``monitor.health.conditions`` turns them into each camera's own thresholds by degrading that
camera's reference image by the limits and measuring it (docs/health.md).

The envelope is stored beside the model (``MODEL.onnx.envelope.json``) with the model's and
the self-test image's sha256: a changed model, test image or minimum recall measures anew.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from monitor.detector import imagestats
from monitor.detector.runners import REFERENCE
from monitor.detector.selftest import SelfTestCase
from monitor.errors import ModelError
from monitor.geometry import boxes as box_ops
from monitor.types import Persons

log = logging.getLogger(__name__)

FORMAT = 1
TRIALS = 4
# Grades per axis, mildest first (the first is the undegraded value).
GRADES: dict[str, tuple[float, ...]] = {
    "gain_low": (1.0, 0.9, 0.85, 0.8, 0.75, 0.7, 0.65, 0.6, 0.55, 0.5, 0.45, 0.4, 0.35, 0.3,
                 0.25, 0.2),
    "gain_high": (1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0),
    "contrast": (1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2),
    "noise": (0.0, 4.0, 8.0, 12.0, 16.0, 20.0, 24.0, 32.0, 40.0),
    "blur": (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0),
    "glare": (0.0, 0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3, 0.5, 0.75, 1.0),
}


@dataclass(frozen=True)
class Envelope:
    """The conditions within which the model's recall on its test figure >= ``min_recall``.

    Gains and contrast are factors of the undegraded image; noise is a standard deviation in
    grey levels and blur a Gaussian sigma, both in pixels of the detector's input
    (``input_width`` px wide)."""

    min_gain: float
    max_gain: float
    min_contrast: float
    max_noise: float
    max_blur: float
    min_recall: float
    input_width: int
    input_height: int
    source: str  # the self-test image: "built-in" or its file
    model_sha256: str = ""
    case_sha256: str = ""
    # the limits as measures of the test image itself (``monitor.detector.imagestats.conditions``):
    # a camera without a reference image is judged by these (docs/health.md)
    absolute: dict[str, float] = field(default_factory=dict)
    # axis -> ((grade, recall), ...) as measured, for the table and the docs
    recall: dict[str, tuple[tuple[float, float], ...]] = field(default_factory=dict)
    # the largest share of the figure's box a clipped band may cover (glare, a sunlit
    # patch); its measure (``absolute["max_saturated"]``) is the clipped share of the image
    max_glare: float = 0.0

    def table(self) -> str:
        """A plain-text table of the limits and the measured recall per grade."""
        lines = [f"envelope of recall >= {self.min_recall:g} on the {self.source} self-test "
                 f"figure ({TRIALS} trials per grade):",
                 f"  brightness gain  {self.min_gain:g} .. {self.max_gain:g}",
                 f"  contrast         >= {self.min_contrast:g} of the original",
                 f"  noise            sigma <= {self.max_noise:g} grey levels",
                 f"  blur             sigma <= {self.max_blur:g} px at the "
                 f"{self.input_width} px model input",
                 f"  glare            a clipped band over <= {self.max_glare:g} of the figure "
                 f"(saturated share <= {self.absolute.get('max_saturated', float('nan')):g} "
                 "of the image)"]
        for axis, rows in self.recall.items():
            cells = "  ".join(f"{g:g}:{r:.2f}" for g, r in rows)
            lines.append(f"  {axis:<10} {cells}")
        lines += [f"warning: {w}" for w in self.no_margin()]
        return "\n".join(lines)

    def no_margin(self) -> list[str]:
        """The axes on which recall already falls at the first degradation: the model has no
        margin there. Live, a camera is then judged only against its own reference's measure
        less ``REFERENCE_MARGIN`` (a normal frame is never a fault); said here, at
        ``monitor model envelope`` time, not as a live fault."""
        first = {axis: steps[0] for axis, steps in GRADES.items()}
        limits = limits_of(self)
        words = {"gain_low": "the least dimming", "gain_high": "the least brightening",
                 "contrast": "the least loss of contrast", "noise": "the least added noise",
                 "blur": "the least blur"}
        return [f"recall falls below {self.min_recall:g} at {words[axis]} of the self-test "
                f"image ({GRADES[axis][1]:g}): the model has no margin for it; a camera is "
                f"judged against its own reference less {REFERENCE_MARGIN:.0%}, and a "
                "better-lit, sharper view (or another model) is advised"
                for axis, value in limits.items() if value == first[axis]]


def degrade(image_bgr: np.ndarray, gain: float = 1.0, contrast: float = 1.0,
            noise: float = 0.0, blur: float = 0.0,
            rng: np.random.Generator | None = None, glare: float = 0.0,
            glare_box: np.ndarray | None = None) -> np.ndarray:
    """One image condition applied in the order light takes: optics (blur), the scene's
    contrast (haze pulls every pixel towards the mean), exposure (gain), sensor noise; then
    glare: a band across ``glare_box`` (x1, y1, x2, y2) over ``glare`` of its height, around
    its middle, clipped to 255 (a sunlit patch on a person: the sensor saturates there)."""
    img = image_bgr.astype(np.float32)
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    if contrast != 1.0:
        mean = float(img.mean())
        img = mean + contrast * (img - mean)
    if gain != 1.0:
        img *= gain
    if noise > 0:
        rng = rng if rng is not None else np.random.default_rng(0)
        img += rng.normal(0.0, noise, img.shape).astype(np.float32)
    if glare > 0 and glare_box is not None:
        x1, y1, x2, y2 = (float(v) for v in np.asarray(glare_box).reshape(4))
        mid, half = 0.5 * (y1 + y2), 0.5 * glare * (y2 - y1)
        img[max(0, round(mid - half)):max(0, round(mid + half)),
            max(0, round(x1)):max(0, round(x2))] = 255.0
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _at_input_scale(case: SelfTestCase, input_size: tuple[int, int]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The case image resized to fit the detector's input, and its box in those pixels: the
    degradations' units are then the detector's own pixels."""
    h, w = case.image.shape[:2]
    scale = min(input_size[0] / w, input_size[1] / h)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    image = cv2.resize(case.image, size, interpolation=cv2.INTER_AREA)
    return image, np.asarray(case.box_px, np.float32) * scale


def _shifted(image: np.ndarray, box: np.ndarray, dx: float, dy: float
             ) -> tuple[np.ndarray, np.ndarray]:
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    out = cv2.warpAffine(image, m, (image.shape[1], image.shape[0]),
                         flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out, box + np.float32([dx, dy, dx, dy])


def recall_at(detect: Callable[[np.ndarray], Persons], image: np.ndarray, box: np.ndarray,
              stride_px: float, min_iou: float, seed: int, **condition: float) -> float:
    """Share of ``TRIALS`` trials (shifts of a half and a quarter grid cell, own noise) in
    which a person box overlaps the known one by ``min_iou``."""
    hits = 0
    shifts = ((0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.25, 0.75))[:TRIALS]
    for k, (fx, fy) in enumerate(shifts):
        shifted, want = _shifted(image, box, fx * stride_px, fy * stride_px)
        rng = np.random.default_rng(seed * 101 + k)
        persons = detect(degrade(shifted, rng=rng, glare_box=want, **condition))
        if len(persons) and float(box_ops.iou_matrix(want[None], persons.boxes_px).max()) \
                >= min_iou:
            hits += 1
    return hits / TRIALS


_PARAM = {"gain_low": "gain", "gain_high": "gain", "contrast": "contrast", "noise": "noise",
          "blur": "blur", "glare": "glare"}


def measure(detect: Callable[[np.ndarray], Persons], case: SelfTestCase,
            input_size: tuple[int, int], stride_px: float, min_recall: float,
            min_iou: float = 0.5, grades: dict[str, tuple[float, ...]] | None = None,
            progress: Callable[[str], None] | None = None) -> Envelope:
    """Measure the envelope of ``detect`` on ``case`` (see the module doc). ModelError when the
    model misses the undegraded figure itself (no envelope at all)."""
    grades = grades or GRADES
    image, box = _at_input_scale(case, input_size)
    limits: dict[str, float] = {}
    table: dict[str, tuple[tuple[float, float], ...]] = {}
    base = recall_at(detect, image, box, stride_px, min_iou, seed=0)
    if base < min_recall:
        raise ModelError(f"the model finds the {case.source} self-test figure in only "
                         f"{100 * base:.0f} % of {TRIALS} shifted copies (needs "
                         f"{100 * min_recall:.0f} %): no operating envelope")
    for n, (axis, steps) in enumerate(grades.items()):
        if progress is not None:
            progress(axis)
        tested = {0: base}

        def passes(g: int, n: int = n, axis: str = axis, steps=steps, tested=tested) -> bool:
            if g not in tested:
                tested[g] = recall_at(detect, image, box, stride_px, min_iou,
                                      seed=n * 1000 + g, **{_PARAM[axis]: steps[g]})
            return tested[g] >= min_recall

        # bisection over the grades (recall falls as a condition worsens): the last passing
        # grade with the next one failing, in about log2(grades) + 1 runs of TRIALS images
        lo, hi = 0, len(steps)  # grade lo passes; grade hi (if any) fails
        if passes(len(steps) - 1):
            lo = hi = len(steps) - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            lo, hi = (mid, hi) if passes(mid) else (lo, mid)
        limits[axis] = steps[lo]
        table[axis] = tuple((steps[g], tested[g]) for g in sorted(tested))
    return Envelope(min_gain=limits["gain_low"], max_gain=limits["gain_high"],
                    min_contrast=limits["contrast"], max_noise=limits["noise"],
                    max_blur=limits["blur"], min_recall=min_recall,
                    input_width=input_size[0], input_height=input_size[1], source=case.source,
                    absolute=absolute_limits(image, limits, box),
                    case_sha256=case_digest(case), recall=table,
                    max_glare=limits.get("glare", 0.0))


# A camera's normal view is within the envelope by definition: a limit derived from it is never
# closer to the view's own measure than this fraction (frame noise, compression, a flicker of the
# lights move a normal frame's measures by a few per cent; a model whose recall falls at the first
# degradation would otherwise fault unchanged footage). Said at `monitor model envelope` time.
REFERENCE_MARGIN = 0.2


def limit_measures(image_bgr: np.ndarray, envelope_limits: dict[str, float],
                   blur_scale: float = 1.0) -> dict[str, float]:
    """An image's measures at the envelope's edges: its mean luminance at the lowest and
    highest gain, its spread at the lowest contrast, its noise with the largest noise added and
    its sharpness at the largest blur (``blur_scale``: the image's pixels per detector-input
    pixel). These are the thresholds a camera whose normal view is this image is judged by;
    each is at least ``REFERENCE_MARGIN`` beyond the image's own measure (a frame like the
    normal view is never outside)."""
    def grey(**condition: float) -> np.ndarray:
        rng = np.random.default_rng(7)
        return cv2.cvtColor(degrade(image_bgr, rng=rng, **condition), cv2.COLOR_BGR2GRAY)

    own = grey()
    own_mean = imagestats.luminance(own)[0]
    low, high = 1.0 - REFERENCE_MARGIN, 1.0 + REFERENCE_MARGIN
    return {
        "min_mean": min(imagestats.luminance(grey(gain=envelope_limits["gain_low"]))[0],
                        own_mean * low),
        "max_mean": max(imagestats.luminance(grey(gain=envelope_limits["gain_high"]))[0],
                        own_mean * high),
        "min_spread": min(
            imagestats.conditions(grey(contrast=envelope_limits["contrast"]))["spread"],
            imagestats.conditions(own)["spread"] * low),
        "max_noise": max(imagestats.noise_sigma(grey(noise=envelope_limits["noise"])),
                         imagestats.noise_sigma(own) * high),
        "min_sharpness": min(
            imagestats.sharpness(grey(blur=envelope_limits["blur"] * blur_scale)),
            imagestats.sharpness(own) * low),
    }


def absolute_limits(image_bgr: np.ndarray, limits: dict[str, float],
                    box: np.ndarray | None = None) -> dict[str, float]:
    """The limits as measures of the test image at the detector's input scale. Sharpness is
    left out: it depends on what the image shows, so only a camera's own reference gives it.
    ``max_saturated`` (with the figure's ``box``): the clipped share of the image with the
    largest glare band the model still sees through."""
    out = limit_measures(image_bgr, limits)
    out.pop("min_sharpness")
    if box is not None and "glare" in limits:
        grey = cv2.cvtColor(degrade(image_bgr, glare=limits["glare"], glare_box=box),
                            cv2.COLOR_BGR2GRAY)
        out["max_saturated"] = imagestats.saturated(grey)
    return {k: round(v, 4) for k, v in out.items()}


def limits_of(envelope: Envelope) -> dict[str, float]:
    return {"gain_low": envelope.min_gain, "gain_high": envelope.max_gain,
            "contrast": envelope.min_contrast, "noise": envelope.max_noise,
            "blur": envelope.max_blur}


def case_digest(case: SelfTestCase) -> str:
    """sha256 of the test image's pixels and box: a changed test image measures anew."""
    digest = hashlib.sha256(np.ascontiguousarray(case.image).tobytes())
    digest.update(json.dumps([round(v, 3) for v in case.box_px]).encode())
    return digest.hexdigest()


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with Path(path).open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def sidecar_path(model_path: str | Path, backend: str = "") -> Path:
    """Where a model's envelope is stored: ``MODEL.onnx.envelope.json`` beside it, measured
    with onnxruntime on the CPU; another backend's (``backend``, e.g. "openvino-bf16", see
    ``backend_tag``) as ``MODEL.onnx.envelope.openvino-bf16.json``."""
    model_path = Path(model_path)
    return model_path.with_name(model_path.name + (f".envelope.{backend}.json" if backend
                                                    else ".envelope.json"))


def backend_tag(detector) -> str:
    """The envelope is measured with the backend that runs: "" for the reference
    (onnxruntime at the model's own precision), else "openvino-bf16" and the like."""
    candidate = detector.backend
    return "" if candidate.backend == REFERENCE else f"{candidate.backend}-{candidate.precision}"


def to_json(envelope: Envelope) -> str:
    data = asdict(envelope)
    data["recall"] = {k: [list(r) for r in v] for k, v in envelope.recall.items()}
    return json.dumps({"format": FORMAT, **data}, indent=1, sort_keys=True)


def from_json(text: str, where: str) -> Envelope:
    """An envelope from its sidecar text; ModelError naming ``where`` when it is malformed."""
    try:
        data = json.loads(text)
        if data.pop("format", None) != FORMAT:
            raise ValueError("unknown format")
        data["recall"] = {k: tuple((float(g), float(r)) for g, r in v)
                          for k, v in data.get("recall", {}).items()}
        env = Envelope(**data)
        values = (env.min_gain, env.max_gain, env.min_contrast, env.max_noise, env.max_blur,
                  env.max_glare)
        if not all(isinstance(v, (int, float)) and np.isfinite(v) and v >= 0 for v in values):
            raise ValueError("a limit is not a finite number >= 0")
        return env
    except (ValueError, TypeError, AttributeError) as exc:
        raise ModelError(f"{where}: not a model envelope ({exc}); remove it or run "
                         "'monitor model envelope'") from None


def write(envelope: Envelope, path: Path) -> Path:
    """Write the sidecar atomically (a half-written envelope never reads as one)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(to_json(envelope) + "\n")
    os.replace(tmp, path)
    return path


def stored(model_path: Path, model_sha256: str, case: SelfTestCase,
           min_recall: float, backend: str = "") -> Envelope | None:
    """The stored envelope when it was measured on this model, test image and minimum recall
    with ``backend`` (``backend_tag``) (None: absent or stale)."""
    path = sidecar_path(model_path, backend)
    if not path.is_file():
        return None
    env = from_json(path.read_text(), str(path))
    if env.model_sha256 != model_sha256 or env.case_sha256 != case_digest(case) \
            or env.min_recall != min_recall or "max_saturated" not in env.absolute:
        return None  # (measured before glare was an axis: measured anew)
    return env


def for_detector(detector, min_recall: float, store: bool = True,
                 progress: Callable[[str], None] | None = None) -> Envelope | None:
    """The envelope of a loaded ``monitor.detector.Detector``: the stored one when it is
    current, else measured (a few seconds) and stored beside the model when ``store`` (a
    read-only model directory only logs). None when the model has no self-test image: then
    there is nothing to measure on (docs/models.md)."""
    case = detector.self_test_case
    if case is None:
        return None
    sha = file_sha256(detector.model_path)
    backend = backend_tag(detector)  # measured with the backend that runs
    env = stored(detector.model_path, sha, case, min_recall, backend)
    if env is not None:
        return env
    layout = detector.layout
    env = measure(detector.detect, case, (layout.input_width, layout.input_height),
                  detector.finest_stride_px(), min_recall, detector.config.self_test_min_iou,
                  progress=progress)
    env = Envelope(**{**asdict(env), "model_sha256": sha, "recall": env.recall})
    if store:
        try:
            write(env, sidecar_path(detector.model_path, backend))
        except OSError as exc:
            log.warning("%s: envelope not stored (%s); measured again at the next start",
                        sidecar_path(detector.model_path, backend), exc)
    return env
