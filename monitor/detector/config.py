"""The detector's settings (``[detector]`` in monitor.toml)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from monitor.errors import ConfigError


@dataclass(frozen=True)
class DetectorConfig:
    # Trades missed persons against false stops; any value in [0, 1] is honoured as given.
    score_threshold: float = 0.5
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
    # Which classes are persons: names (as in the model's metadata) or class ids. None: every
    # class named "person", else class 0 with a warning naming the classes found.
    person_classes: tuple[str | int, ...] | None = None
    # How far a box's bottom edge may lie below the real feet, in cells of the finest output
    # grid: the zone checks also test the feet this much higher (see zones.check_persons).
    foot_uncertainty_cells: float = 1.0
    # onnxruntime's workers spin after each run by default; on a 2-core box that steals the CPU
    # the rest of the pipeline (video decode, health) needs right after inference.
    spin_wait: bool = False
    # Self-test: an image with one known person (x1 y1 x2 y2 in that image's pixels) the model
    # must find. Built in for the synthetic model; needed for any other model.
    self_test_image: str | None = None
    self_test_box: tuple[float, float, float, float] | None = None
    self_test_period_s: float = 10.0  # 0 = only at start
    self_test_min_iou: float = 0.5  # how well a detected box must cover the known one

    def __post_init__(self) -> None:
        if not (math.isfinite(self.score_threshold) and 0.0 <= self.score_threshold <= 1.0):
            raise ConfigError(f"detector.score_threshold: {self.score_threshold} not in [0, 1]")
        if self.top_k < 1 or self.threads < 1 or self.input_size < 32:
            raise ConfigError("detector.top_k, threads must be >= 1 and input_size >= 32")
        if not 0.0 <= self.foot_uncertainty_cells <= 10.0:
            raise ConfigError("detector.foot_uncertainty_cells: must be within [0, 10]")
        if self.person_classes is not None and len(self.person_classes) == 0:
            raise ConfigError("detector.person_classes: empty; name at least one class "
                              "(or leave it out for every class named person)")
        if not (math.isfinite(self.self_test_period_s) and self.self_test_period_s >= 0):
            raise ConfigError(f"detector.self_test_period_s: {self.self_test_period_s} is not "
                              f"a number of seconds >= 0 (0 = only at start)")
        if not (math.isfinite(self.self_test_min_iou) and 0.0 < self.self_test_min_iou <= 1.0):
            raise ConfigError(f"detector.self_test_min_iou: {self.self_test_min_iou} not in "
                              f"(0, 1]")
        if (self.self_test_image is None) != (self.self_test_box is None):
            raise ConfigError("detector.self_test_image and detector.self_test_box go together: "
                              "the image and the box of the person in it")
        if self.self_test_box is not None:
            x1, y1, x2, y2 = self.self_test_box
            if not (all(math.isfinite(v) for v in self.self_test_box) and 0 <= x1 < x2
                    and 0 <= y1 < y2):
                raise ConfigError(f"detector.self_test_box: {list(self.self_test_box)} is not "
                                  f"x1 y1 x2 y2 pixels with x1 < x2, y1 < y2")
