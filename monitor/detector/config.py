"""The detector's settings (``[detector]`` in monitor.toml)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from monitor.schema import Bool, ConfigPath, Float, Fraction, Int, NonNegative, Text, section

Box = tuple[Float, Float, Float, Float]


@section("detector")
class DetectorConfig:
    # Trades missed persons against false stops; any value in [0, 1] is honoured as given.
    score_threshold: Fraction = 0.5
    nms_iou: Fraction = 0.45
    # candidates kept before NMS; more is reported as an overflow fault
    top_k: Annotated[Int, Field(ge=1)] = 512
    merge_iou: Fraction = 0.5
    merge_ios: Fraction = 0.7
    merge_touch_px: Float = 1.0  # in model-input pixels; < 0 disables merging by touch
    threads: Annotated[Int, Field(ge=1)] = 2
    input_size: Annotated[Int, Field(ge=32)] = 416  # for models with a dynamic input size
    # Models with a dynamic input size: run each frame at the smallest input that holds it at
    # input_size's scale (a 16:9 frame at 416x288: ~30 % less inference, the same detections
    # inside the image). False: always the full input_size square.
    rectangular_input: Bool = True
    layout: Text | None = None  # force a layout instead of detecting it
    anchors: tuple[tuple[Float, Float], ...] | None = None  # darknet: override anchors
    masks: tuple[tuple[Int, ...], ...] | None = None  # darknet: override anchor masks
    # Which classes are persons: names (as in the model's metadata) or class ids. None: every
    # class named "person", else class 0 with a warning naming the classes found.
    person_classes: tuple[Text | Int, ...] | None = None
    # How far a box's bottom edge may lie below the real feet, in cells of the finest output
    # grid: the zone checks also test the feet this much higher (see zones.check_persons).
    foot_uncertainty_cells: Annotated[Float, Field(ge=0, le=10)] = 1.0
    # several cameras: frames that are ready together run as one batch (models with a dynamic
    # batch dimension; others run them one after the other). Off by default: on 2-core CPUs a
    # batch of n frames costs n single inferences, and every frame of it waits for the whole
    # batch (4 cameras at 10 fps: p99 capture-to-command 189 ms batched, 94 ms in turn, int8)
    batch_cameras: Bool = False
    # onnxruntime's workers spin after each run by default; on a 2-core box that steals the CPU
    # the rest of the pipeline (video decode, health) needs right after inference.
    spin_wait: Bool = False
    # Which runtime runs the model (monitor/detector/runners.py, docs/models.md "Backends"):
    # "auto" measures every backend and precision this host has at start and runs the fastest
    # whose persons agree with onnxruntime's on the self-test figure and the envelope's
    # degraded copies of it; a named backend must agree too, or the start is refused.
    backend: Literal["auto", "onnxruntime", "onnxruntime-cuda", "onnxruntime-tensorrt",
                     "onnxruntime-openvino", "openvino", "openvino-gpu"] = "auto"
    # "auto": the fastest agreeing one (an int8 model runs int8); bf16 needs a CPU with it
    # (AVX-512 BF16 or AMX), fp16 a GPU
    precision: Literal["auto", "fp32", "bf16", "fp16", "int8"] = "auto"
    # persons found by both / by either (the measure and threshold of `monitor model quantize`)
    backend_min_agreement: Annotated[Float, Field(gt=0, le=1)] = 0.98
    # the start-up measurement's bound (s); its result is cached per model and host
    backend_budget_s: Annotated[Float, Field(gt=0, le=600)] = 20.0
    # Self-test: an image with one known person (x1 y1 x2 y2 in that image's pixels) the model
    # must find. Built in for the synthetic model; needed for any other model.
    self_test_image: ConfigPath = None
    self_test_box: Box | None = None
    self_test_period_s: NonNegative = 10.0  # 0 = only at start
    # how well a detected box must cover the known one
    self_test_min_iou: Annotated[Float, Field(gt=0, le=1)] = 0.5

    @model_validator(mode="after")
    def _rules(self) -> DetectorConfig:
        if self.person_classes is not None and len(self.person_classes) == 0:
            raise ValueError("person_classes: empty; name at least one class (or leave it out "
                             "for every class named person)")
        if (self.self_test_image is None) != (self.self_test_box is None):
            raise ValueError("self_test_image and self_test_box go together: the image and the "
                             "box of the person in it")
        if self.self_test_box is not None:
            x1, y1, x2, y2 = self.self_test_box
            if not (0 <= x1 < x2 and 0 <= y1 < y2):
                raise ValueError(f"self_test_box: {list(self.self_test_box)} is not x1 y1 x2 y2 "
                                 f"pixels with x1 < x2, y1 < y2")
        return self
