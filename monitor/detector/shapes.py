"""Every run's output shapes checked against the shapes the layout was found with.

The layout of a model is decided once, at load, from its shapes. A model whose outputs later
come back in another shape (an extra dimension, no rows at all, another batch size: a dynamic
export that behaves differently on some frames) would otherwise be decoded as best it can: no
rows reads as "no persons", a batch of two as the first batch only. A shape that is not the one
found at load is a ``DetectorError`` naming both (the pipeline's detector fault, STOP).

A model with a dynamic input runs each frame shape at its own input size (a rectangular input,
``ModelLayout.rect``): there the grids follow the input, and :meth:`OutputShapes.at_input`
derives the shapes to expect from the ones found at load, so a frame shape never met before is
checked as strictly as the first.

What may change from run to run: the batch (dimension 0, it must equal the frames sent), the
number of detections of an end-to-end export (K of ``(batch, K, 6)``) and of the ONNX-zoo
selected indices. Every other dimension is fixed by the input size and must stay as found.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from monitor.detector.layouts import ModelLayout, grid_cells
from monitor.errors import DetectorError


def _variable_dims(kind: str, index: int, rank: int) -> frozenset[int]:
    """Dimensions that count detections (they may differ between runs)."""
    if kind == "end2end":
        return frozenset({1})
    if kind == "zoo" and index == 2:  # selected indices: (K, 3) or (1, K, 3)
        return frozenset({rank - 2})
    return frozenset()


@dataclass(frozen=True)
class OutputShapes:
    """The shape of each output at batch 1, as found at load, and its counting dimensions."""

    kind: str
    names: tuple[str, ...]
    shapes: tuple[tuple[int, ...], ...]
    variable: tuple[frozenset[int], ...]

    @classmethod
    def found(cls, layout: ModelLayout, names: Sequence[str],
              outputs: Sequence[np.ndarray]) -> OutputShapes:
        """From one run at batch 1 (the warm-up); DetectorError if it is not at batch 1."""
        shapes = tuple(tuple(int(d) for d in np.shape(o)) for o in outputs)
        variable = tuple(_variable_dims(layout.kind, i, len(s)) for i, s in enumerate(shapes))
        out = cls(layout.kind, tuple(names), shapes, variable)
        out.check(outputs, 1)
        return out

    def at_input(self, load: ModelLayout, layout: ModelLayout) -> OutputShapes:
        """The shapes expected at ``layout``'s input size, found at ``load``'s: a darknet
        head's grid and the rows (columns for yolov8) of a single output scale with the input;
        an end-to-end export's detections are counted anyway."""
        if (layout.input_width, layout.input_height) == (load.input_width, load.input_height):
            return self
        shapes = []
        for shape in self.shapes:
            s = list(shape)
            if self.kind == "darknet" and len(s) == 4:
                hy, wx = (1, 2) if load.heads_nhwc else (2, 3)
                s[hy] = shape[hy] * layout.input_height // load.input_height
                s[wx] = shape[wx] * layout.input_width // load.input_width
            elif self.kind in ("yolov5", "yolov8", "yolox") and len(s) == 3:
                dim = 2 if self.kind == "yolov8" else 1
                now = grid_cells(layout.input_height, layout.input_width, load.strides)
                s[dim] = shape[dim] * now // grid_cells(load.input_height, load.input_width,
                                                        load.strides)
            shapes.append(tuple(s))
        return replace(self, shapes=tuple(shapes))

    def check(self, outputs: Sequence[np.ndarray], batch: int) -> None:
        """DetectorError unless ``outputs`` of a run on ``batch`` frames have the shapes found
        at load (the batch dimension scaled, counting dimensions free)."""
        if len(outputs) != len(self.shapes):
            raise DetectorError(f"model gave {len(outputs)} outputs, {len(self.shapes)} at load")
        for name, out, found, free in zip(self.names, outputs, self.shapes, self.variable,
                                          strict=True):
            shape = tuple(int(d) for d in np.shape(out))
            if self._fits(shape, found, free, batch):
                continue
            want = tuple("K" if i in free else batch if i == 0 else d
                         for i, d in enumerate(found))
            raise DetectorError(
                f"model output {name!r} has shape {shape}, the {self.kind} layout found at load "
                f"expects {want} for {batch} frame(s): the model's output changed, its "
                f"detections cannot be read (never taken as no persons)")

    @staticmethod
    def _fits(shape: tuple[int, ...], found: tuple[int, ...], free: frozenset[int],
              batch: int) -> bool:
        if len(shape) != len(found):
            return False
        for i, (d, f) in enumerate(zip(shape, found, strict=True)):
            if i in free:
                continue
            if d != (batch if i == 0 else f) or (i > 0 and d < 1):
                return False
        return True
