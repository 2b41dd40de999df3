"""Which output layout a model has, decided by evidence: shapes, metadata, a probe run.

Pure helpers (:func:`classify_single_output`, :func:`resolve_person_classes`) hold the rules;
:func:`inspect_model` gathers the evidence from a runner (``monitor.detector.runners``), whatever
runtime it is.
"""

from __future__ import annotations

import ast
import contextlib
import json
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from monitor.detector.runners import runtime_message
from monitor.errors import ConfigError, ModelError

if TYPE_CHECKING:
    from monitor.detector.config import DetectorConfig

LAYOUTS = ("darknet", "yolov5", "yolov8", "end2end", "zoo", "yolox")
# Darknet defaults: tiny-YOLOv3 (2 heads) and YOLOv3 (3 heads); coarse head first.
TINY_ANCHORS = ((10, 14), (23, 27), (37, 58), (81, 82), (135, 169), (344, 319))
TINY_MASKS = ((3, 4, 5), (1, 2, 3))
V3_ANCHORS = ((10, 13), (16, 30), (33, 23), (30, 61), (62, 45), (59, 119), (116, 90),
              (156, 198), (373, 326))
V3_MASKS = ((6, 7, 8), (3, 4, 5), (0, 1, 2))
# Output strides of single-output exports: P3-P5, and P3-P6 of the "6" models (e.g. yolov5s6).
STRIDE_SETS = ((8, 16, 32), (8, 16, 32, 64))


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
    person_class: int = 0  # the first of person_classes (kept for older callers)
    anchors: tuple[tuple[float, float], ...] = ()
    masks: tuple[tuple[int, ...], ...] = ()
    heads_nhwc: bool = False
    strides: tuple[int, ...] = (8, 16, 32)
    names: dict[int, str] = field(default_factory=dict)
    person_classes: tuple[int, ...] = ()  # empty: (person_class,)
    # The input's height and width are dynamic: a frame runs at the smallest input that holds
    # it at the full input's scale (monitor.detector.preprocess.fitted_input).
    rect: bool = False

    @property
    def persons(self) -> tuple[int, ...]:
        """The class ids whose detections are persons."""
        return self.person_classes or (self.person_class,)


def grid_cells(height: int, width: int, strides: tuple[int, ...]) -> int:
    """Output cells of a one-row-per-cell (anchor-free) export at this input size."""
    return sum((height // s) * (width // s) for s in strides)


def classify_single_output(rows: int, cols: int, height: int, width: int,
                           ) -> tuple[str, tuple[int, ...]] | None:
    """The layout of a single 1 x rows x cols output, by evidence; None if none fits.

    Rows equal to the grid cells of the input (8400 at 640) mean one raw prediction per cell
    (YOLOX); three times that (25200 at 640) means 3 anchors per cell (YOLOv5). Only then does a
    6-column output mean an end-to-end export (x1 y1 x2 y2 score class, K of them): a one-class
    YOLOv5 or YOLOX also has 6 columns.
    """
    if 5 <= rows < cols:
        return "yolov8", (8, 16, 32)  # channels first: 4 box + classes, then N columns
    if cols < 6:
        return None
    for strides in STRIDE_SETS:
        cells = grid_cells(height, width, strides)
        if rows == cells:
            return "yolox", strides
        if rows == 3 * cells:
            return "yolov5", strides
    if cols == 6:
        return "end2end", (8, 16, 32)
    return "yolov5", (8, 16, 32)


def resolve_person_classes(wanted: tuple[str | int, ...] | None, names: dict[int, str],
                           num_classes: int) -> tuple[tuple[int, ...], str | None]:
    """Person class ids from the config's names/ids, and a warning when they were guessed."""
    listed = _name_list(names)
    if wanted:
        ids = []
        by_name = {v.strip().lower(): k for k, v in names.items()}
        for item in wanted:
            if isinstance(item, int) and not isinstance(item, bool):
                if not 0 <= item < num_classes:
                    raise ConfigError(f"detector.person_classes: class {item} does not exist "
                                      f"(the model has classes 0..{num_classes - 1})")
                ids.append(item)
            elif str(item).strip().lower() in by_name:
                ids.append(by_name[str(item).strip().lower()])
            else:
                raise ConfigError(f"detector.person_classes: the model has no class named "
                                  f"{item!r} ({listed})")
        return tuple(sorted(set(ids))), None
    found = tuple(sorted(k for k, v in names.items() if v.strip().lower() == "person"))
    if found:
        return found, None
    if names:
        return (0,), (f"no class named 'person' in the model ({listed}): taking class 0 "
                      f"({names.get(0, '?')!r}) as persons; set detector.person_classes")
    if num_classes not in (1, 80):  # 80 unnamed classes: COCO order, person first
        return (0,), (f"the model does not name its {num_classes} classes: taking class 0 as "
                      f"persons; set detector.person_classes")
    return (0,), None


def _name_list(names: dict[int, str], limit: int = 12) -> str:
    if not names:
        return "classes not named in the model"
    items = [f"{k}: {v}" for k, v in sorted(names.items())]
    more = f", ... ({len(items)} in all)" if len(items) > limit else ""
    return "classes " + ", ".join(items[:limit]) + more


def parse_names(raw: str | None) -> dict[int, str]:
    """Class names from metadata: JSON or a Python dict literal (Ultralytics), or a list."""
    if not raw:
        return {}
    try:
        data = json.loads(raw)
    except ValueError:
        try:
            data = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            return {}
    if isinstance(data, list):
        return dict(enumerate(map(str, data)))
    if isinstance(data, dict):
        with contextlib.suppress(ValueError, TypeError):
            return {int(k): str(v) for k, v in data.items()}
    return {}


def _dim(d, default: int) -> int:
    return d if isinstance(d, int) and d > 0 else default


def _static(shape) -> bool:
    return all(isinstance(d, int) and d > 0 for d in shape)


def _parse_list(raw: str) -> list[int]:
    return [int(v) for v in raw.strip("[]() ").replace(",", " ").split()]


def probe_output_shapes(runner, input_name: str, height: int, width: int, nhwc: bool,
                        ) -> list[tuple[int, ...]]:
    """Output shapes of one run on a blank input: the evidence when the file declares
    symbolic (dynamic-axes) output sizes."""
    feeds = {input_name: np.zeros((1, height, width, 3) if nhwc else (1, 3, height, width),
                                  np.float32)}
    for extra in runner.inputs:
        if extra.name != input_name:
            raise ModelError(f"model input {extra.name!r} is not known; expected one image input")
    try:
        outputs = runner.run(feeds)
    except Exception as exc:  # the runtime's own exception types
        raise ModelError(f"probe run at {width}x{height} failed ({runtime_message(exc)}); set "
                         f"detector.input_size to the model's input size") from None
    return [tuple(int(d) for d in np.shape(o)) for o in outputs]


def inspect_model(runner, config: DetectorConfig) -> tuple[ModelLayout, str | None]:
    """The layout of a loaded model (a ``runners.Runner``) and a warning (or None); ModelError
    if none fits."""
    inputs, outputs = runner.inputs, runner.outputs
    meta = dict(runner.metadata)
    names = parse_names(meta.get("names"))
    in_names = [i.name for i in inputs]
    shapes = [tuple(o.shape) for o in outputs]
    found = f"inputs {[(i.name, tuple(i.shape)) for i in inputs]}, outputs {shapes}"
    kind = config.layout or meta.get("layout")
    if kind is not None and kind not in LAYOUTS:
        raise ModelError(f"unknown layout {kind!r}; known: {', '.join(LAYOUTS)}")

    if kind == "zoo" or (kind is None and "image_shape" in in_names and len(outputs) == 3):
        image = next(i for i in inputs if i.name != "image_shape")
        size = config.input_size
        names = names or {0: "person"}
        persons, warning = resolve_person_classes(config.person_classes, names, 80)
        return ModelLayout("zoo", image.name, _dim(image.shape[3], size),
                           _dim(image.shape[2], size), pad_value=128, names=names,
                           person_class=persons[0], person_classes=persons), warning

    image = inputs[0]
    shp = list(image.shape)
    if len(shp) != 4:
        raise ModelError(f"model input {image.name} has shape {tuple(shp)}; expected 4-D image")
    nhwc = shp[3] == 3 and shp[1] != 3
    ih = _dim(shp[1] if nhwc else shp[2], config.input_size)
    iw = _dim(shp[2] if nhwc else shp[3], config.input_size)
    imgsz = meta.get("imgsz")
    if imgsz and not _static(shp[1:3] if nhwc else shp[2:4]):
        with contextlib.suppress(ValueError):
            ih, iw = (list(_parse_list(imgsz)) * 2)[:2]
    # an output declared without any shape reads as () here, like a scalar: no detector
    # output is a scalar, so it is probed like a symbolic one
    if not all(_static(s) and s for s in shapes):
        shapes = probe_output_shapes(runner, image.name, ih, iw, nhwc)
        found += f" (at {iw}x{ih}: {shapes})"
        for out, shape in zip(outputs, shapes, strict=True):
            if not shape:
                raise ModelError(f"model output {out.name!r} is a scalar (no shape declared, "
                                 f"none in a probe run): no known output layout: {found}")
    rect = config.rectangular_input and not _static(shp[1:3] if nhwc else shp[2:4])
    base = dict(input_name=image.name, input_width=iw, input_height=ih, input_nhwc=nhwc,
                names=names, rect=rect)

    if kind == "darknet" or (kind is None and len(outputs) in (2, 3)
                             and all(len(s) == 4 for s in shapes)):
        layout = _darknet_layout(shapes, meta, config, base, found)
    else:
        if len(shapes) != 1 or len(shapes[0]) != 3:
            raise ModelError(f"no known output layout: {found}")
        _, rows, cols = shapes[0]
        guess = classify_single_output(rows, cols, ih, iw)
        strides = guess[1] if guess else (8, 16, 32)
        kind = kind or (guess[0] if guess else None)
        if kind is None or kind == "darknet":
            raise ModelError(f"no known output layout: {found}")
        nc = {"yolov8": rows - 4, "yolov5": cols - 5, "yolox": cols - 5}.get(
            kind, len(names) or 80)
        if nc < 1:
            raise ModelError(f"no known output layout ({kind} without classes): {found}")
        if kind == "yolox":
            layout = ModelLayout(kind, rgb=False, scale=1.0, pad_value=114, centered=False,
                                 num_classes=nc, strides=strides, **base)
        else:
            layout = ModelLayout(kind, num_classes=nc, strides=strides, **base)
    persons, warning = resolve_person_classes(config.person_classes, names, layout.num_classes)
    if max(persons) >= layout.num_classes:
        raise ConfigError(f"detector.person_classes: class {max(persons)} does not exist (the "
                          f"model has classes 0..{layout.num_classes - 1})")
    return replace(layout, person_class=persons[0], person_classes=persons), warning


def _consistent_grids(grids: list[tuple[int, int]], height: int, width: int) -> bool:
    """Every head's grid has the input's aspect (stride the same along x and y)."""
    return all(gy > 0 and gx > 0 and height * gx == width * gy for gy, gx in grids)


def _darknet_layout(shapes, meta, config: DetectorConfig, base: dict, found: str) -> ModelLayout:
    if not all(len(s) == 4 and _static(s[1:]) for s in shapes):
        raise ModelError(f"no known output layout (darknet heads need 4-D shapes): {found}")
    ih, iw = base["input_height"], base["input_width"]
    # The channel count is the same for every head; the grids differ and follow the input.
    nchw = (len({s[1] for s in shapes}) == 1 and shapes[0][1] % 3 == 0
            and _consistent_grids([(s[2], s[3]) for s in shapes], ih, iw))
    nhwc = (len({s[3] for s in shapes}) == 1 and shapes[0][3] % 3 == 0
            and _consistent_grids([(s[1], s[2]) for s in shapes], ih, iw))
    if not (nchw or nhwc):
        raise ModelError(f"no known output layout (darknet heads whose grids do not match the "
                         f"{iw}x{ih} input): {found}")
    heads_nhwc = nhwc and not nchw
    channels = shapes[0][3] if heads_nhwc else shapes[0][1]
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
                       masks=tuple(tuple(m) for m in masks), heads_nhwc=heads_nhwc, **base)


def _json(raw: str | None):
    if not raw:
        return None
    try:
        return json.loads(raw)
    except ValueError:
        return None
