"""The synthetic tiny-YOLOv3 model: the JKU Linz 2024 thesis' layer table, analytic weights.

Not trained, not random: every weight is chosen so that the network is a genuine detector of the
persons drawn by ``monitor.scene`` (saturated magenta work wear). See models/README.md (the model
card) for what it detects and what it does not.

How the weights work (input: RGB in [0, 1], NCHW 1x3x416x416, Darknet letterbox):

1. conv0 computes z = s * (R + B - 2G - T) per pixel (centre tap only) into two channels,
   a = leaky(z) and b = leaky(z - 1). Both are increasing in z, so after max-pooling
   a - b - 0.1 = 0.9 * clamp(max z, 0, 1): a clean "work-wear colour present" indicator.
2. conv2..conv8 carry two maps down to the 26x26 grid: P (presence: identity centre taps and
   max-pools, so P of a cell = the indicator's maximum over its 16x16 pixels) and M (mass: a 2x2
   mean before each max-pool, roughly the share of the cell covered).
3. The 26x26 head's 3x3 conv forms two soft binary gates, "P >= 0.5" and "sum of M over the 3x3
   neighbourhood >= min_mass" (so a same-colour sticker smaller than a person does not fire), each
   as leaky(k x) - leaky(k x - 1), and the last 1x1 conv ANDs them into the objectness logit.
4. Box outputs are constant: tx = ty = 0 puts the box on the cell centre, tw and th make it a
   cell wide plus a small margin. A person is the union of the cells it covers (see
   ``monitor.geometry.boxes.merge_touching``). The 13x13 head never fires (objectness bias -20).

All other weights are zero: the graph still has exactly the thesis' 8,849,182 parameters and costs
the same inference time as a trained tiny-YOLOv3.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

INPUT_SIZE = 416
NUM_CLASSES = 80
# Darknet yolov3-tiny anchors (pixels at 416) and the cfg's masks: 13x13 head, then 26x26 head.
ANCHORS = ((10, 14), (23, 27), (37, 58), (81, 82), (135, 169), (344, 319))
MASKS = ((3, 4, 5), (1, 2, 3))
COCO_NAMES = (
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat",
    "traffic light", "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog",
    "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella",
    "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard", "sports ball", "kite",
    "baseball bat", "baseball glove", "skateboard", "surfboard", "tennis racket", "bottle",
    "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple", "sandwich", "orange",
    "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair", "couch", "potted plant",
    "bed", "dining table", "toilet", "tv", "laptop", "mouse", "remote", "keyboard", "cell phone",
    "microwave", "oven", "toaster", "sink", "refrigerator", "book", "clock", "vase", "scissors",
    "teddy bear", "hair drier", "toothbrush")
LEAKY = 0.1


@dataclass(frozen=True)
class SyntheticWeights:
    """The few numbers that set the analytic weights."""

    colour_threshold: float = 1.0  # on R + B - 2G with channels in [0, 1]
    colour_gain: float = 5.0  # the indicator is full at threshold + 1 / gain
    presence_gain: float = 4.0
    min_mass: float = 0.75  # sum of 3x3-cell neighbourhood mass (a blurred covered share)
    mass_gain: float = 10.0
    # Each row of the 3x3-cell mass sum is capped at this before the sum (see build_weights):
    # it changes no decision but bounds the head's activations, so int8 keeps them exact.
    row_mass_cap: float = 1.0
    box_margin_px: float = 0.8  # each cell box grows by this on every side (416 pixels)
    objectness_gain: float = 20.0


def _conv(name: str, cin: int, cout: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    return np.zeros((cout, cin, k, k), np.float32), np.zeros((cout,), np.float32)


def build_weights(p: SyntheticWeights) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """All conv weights and biases (BatchNorm folded), by layer name."""
    w: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    # conv0: 3 -> 16 at 416; channel order of the input is R, G, B.
    W, B = _conv("conv0", 3, 16, 3)
    colour = np.array([1.0, -2.0, 1.0], np.float32) * p.colour_gain
    W[0, :, 1, 1] = colour
    W[1, :, 1, 1] = colour
    B[0] = -p.colour_gain * p.colour_threshold
    B[1] = B[0] - 1.0
    w["conv0"] = (W, B)
    # conv2: 16 -> 32 at 208: P = clamp indicator, M = its 2x2 mean.
    W, B = _conv("conv2", 16, 32, 3)
    W[0, 0, 1, 1], W[0, 1, 1, 1], B[0] = 1 / 0.9, -1 / 0.9, -0.1 / 0.9
    W[1, 0], W[1, 1], B[1] = 1 / 8.1, -1 / 8.1, -0.1 / 0.9
    w["conv2"] = (W, B)
    # conv4, conv6: carry P (identity) and M (2x2 mean) down to 52 and 26.
    for name, cin, cout in (("conv4", 32, 64), ("conv6", 64, 128)):
        W, B = _conv(name, cin, cout, 3)
        W[0, 0, 1, 1] = 1.0
        W[1, 1] = 1 / 9
        w[name] = (W, B)
    # conv8: 128 -> 256 at 26 (the route to the fine head): P (identity), and the mass's
    # horizontal 3-cell sum H as the pair leaky(H / cap), leaky(H / cap - 1), plus a constant
    # 0.1 channel. The head's conv21 takes (pair difference - constant) = 0.9 clamp(H / cap, 0, 1)
    # from its three rows: the 3x3 sum with each row capped. Capping a row at cap >= min_mass +
    # 1 / mass_gain changes no gate decision (one full row already passes), and it bounds every
    # activation of the head to a few units; the constant channel is zero in conv21's padding
    # exactly as a real zero-mass row would contribute nothing.
    W, B = _conv("conv8", 128, 256, 3)
    W[0, 0, 1, 1] = 1.0
    W[1, 1, 1, :] = W[2, 1, 1, :] = 1.0 / p.row_mass_cap
    B[2] = -1.0
    B[3] = 0.1
    w["conv8"] = (W, B)
    for name, cin, cout, k in (("conv10", 256, 512, 3), ("conv12", 512, 1024, 3),
                               ("conv13", 1024, 256, 1), ("conv14", 256, 512, 3),
                               ("conv18", 256, 128, 1)):
        w[name] = _conv(name, cin, cout, k)
    # conv15: the 13x13 head never fires.
    W, B = _conv("conv15", 512, 255, 1)
    B[4::85] = -20.0
    w["conv15"] = (W, B)
    # conv21: 384 -> 256 at 26; inputs 0..127 upsampled (zero), 128.. the route (P=128; the
    # capped-mass pair 129, 130 and the constant 131).
    W, B = _conv("conv21", 384, 256, 3)
    P, M1, M2, ONE = 128, 129, 130, 131
    for ch, extra in ((0, 0.0), (1, -1.0)):
        W[ch, P, 1, 1] = p.presence_gain
        B[ch] = -0.5 * p.presence_gain + extra
    row = p.mass_gain * p.row_mass_cap / 0.9
    for ch, extra in ((2, 0.0), (3, -1.0)):
        W[ch, M1, :, 1] = row
        W[ch, M2, :, 1] = W[ch, ONE, :, 1] = -row
        B[ch] = -p.min_mass * p.mass_gain + extra
    w["conv21"] = (W, B)
    # conv22: 256 -> 255 at 26, linear: anchor slot 0 of this head fires, slots 1 and 2 never.
    W, B = _conv("conv22", 256, 255, 1)
    anchor_w, anchor_h = ANCHORS[MASKS[1][0]]
    size = 16.0 + 2 * p.box_margin_px
    B[2], B[3] = math.log(size / anchor_w), math.log(size / anchor_h)
    g = p.objectness_gain
    W[4, 0, 0, 0], W[4, 1, 0, 0], W[4, 2, 0, 0], W[4, 3, 0, 0] = g, -g, g, -g
    B[4] = -1.5 * g
    B[5] = 10.0  # person
    B[6:85] = -10.0
    B[85 + 4], B[170 + 4] = -20.0, -20.0
    w["conv22"] = (W, B)
    return w


def build_model(p: SyntheticWeights | None = None, input_size: int = INPUT_SIZE,
                ) -> onnx.ModelProto:
    """The ONNX graph of the thesis' Table A.9 (Darknet yolov3-tiny), opset 13.

    ``input_size`` (a multiple of 32) changes only the input and grid sizes: the weights are
    the same, so 320 or 256 trade accuracy on small persons for speed.
    """
    if input_size % 32 or input_size < 64:
        raise ValueError(f"input size {input_size} is not a multiple of 32 (>= 64)")
    p = p or SyntheticWeights()
    weights = build_weights(p)
    nodes: list[onnx.NodeProto] = []
    inits: list[onnx.TensorProto] = []

    def conv(name: str, x: str, leaky: bool = True) -> str:
        W, B = weights[name]
        inits.append(numpy_helper.from_array(W, f"{name}.weight"))
        inits.append(numpy_helper.from_array(B, f"{name}.bias"))
        k = W.shape[2]
        out = f"{name}.out"
        nodes.append(helper.make_node("Conv", [x, f"{name}.weight", f"{name}.bias"], [out],
                                      name=name, kernel_shape=[k, k], pads=[k // 2] * 4))
        if not leaky:
            return out
        nodes.append(helper.make_node("LeakyRelu", [out], [f"{name}.act"], alpha=LEAKY,
                                      name=f"{name}.leaky"))
        return f"{name}.act"

    def maxpool(name: str, x: str, stride: int = 2) -> str:
        pads = [0, 0, 1, 1] if stride == 1 else [0, 0, 0, 0]
        nodes.append(helper.make_node("MaxPool", [x], [f"{name}.out"], name=name,
                                      kernel_shape=[2, 2], strides=[stride, stride], pads=pads))
        return f"{name}.out"

    x = "images"
    x = maxpool("pool1", conv("conv0", x))
    x = maxpool("pool3", conv("conv2", x))
    x = maxpool("pool5", conv("conv4", x))
    x = maxpool("pool7", conv("conv6", x))
    route = conv("conv8", x)
    x = maxpool("pool11", conv("conv10", maxpool("pool9", route)), stride=1)
    x13 = conv("conv13", conv("conv12", x))
    head13 = conv("conv15", conv("conv14", x13), leaky=False)
    up_in = conv("conv18", x13)
    # a Constant node, not an initializer: the initializers are exactly the conv parameters
    scales = numpy_helper.from_array(np.array([1, 1, 2, 2], np.float32))
    nodes.append(helper.make_node("Constant", [], ["up.scales"], name="up.scales", value=scales))
    nodes.append(helper.make_node("Resize", [up_in, "", "up.scales"], ["up.out"], name="up",
                                  mode="nearest"))
    nodes.append(helper.make_node("Concat", ["up.out", route], ["route.out"], axis=1,
                                  name="route20"))
    head26 = conv("conv22", conv("conv21", "route.out"), leaky=False)
    nodes.append(helper.make_node("Identity", [head13], ["output_13"], name="out13"))
    nodes.append(helper.make_node("Identity", [head26], ["output_26"], name="out26"))
    graph = helper.make_graph(
        nodes, "tiny_yolov3_synthetic",
        # height and width are dynamic (multiples of 32): a 16:9 frame runs at 416x288, not
        # in the full square (imgsz below; monitor.detector.preprocess.fitted_input)
        [helper.make_tensor_value_info("images", TensorProto.FLOAT,
                                       ["batch", 3, "height", "width"])],
        [helper.make_tensor_value_info("output_13", TensorProto.FLOAT,
                                       ["batch", 255, "height/32", "width/32"]),
         helper.make_tensor_value_info("output_26", TensorProto.FLOAT,
                                       ["batch", 255, "height/16", "width/16"])],
        inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)],
                              producer_name="workcell-monitor", producer_version="1")
    model.ir_version = 8
    meta = {
        "layout": "darknet",
        "imgsz": str(input_size),  # the full input; smaller rectangles run too
        "anchors": json.dumps(ANCHORS),
        "masks": json.dumps(MASKS),
        "names": json.dumps(dict(enumerate(COCO_NAMES))),
        "description": "tiny-YOLOv3 (seeds' Table A.9) with analytic weights: detects persons "
                       "in saturated magenta work wear; see models/README.md",
        "synthetic_weights": json.dumps(p.__dict__, sort_keys=True),
    }
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(model)
    return model


def write_model(path: str | Path, p: SyntheticWeights | None = None,
                input_size: int = INPUT_SIZE) -> str:
    """Write the model atomically; returns the file's SHA-256."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = build_model(p, input_size).SerializeToString(deterministic=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)
    sha = hashlib.sha256(data).hexdigest()
    _place_envelope(path, sha)
    return sha


# The operating envelope of the default build (`monitor model envelope`), measured once and
# shipped: it names the model's and the self-test figure's sha256, so it is used only for these
# exact bytes (the monitor checks both when it reads it) and saves every fresh install the ~5-10 s
# of measuring it at the first start. A changed build or test figure is measured anew.
SHIPPED_ENVELOPE = Path(__file__).with_name("tiny-yolov3-synthetic.onnx.envelope.json")


def _place_envelope(model_path: Path, sha: str) -> None:
    try:
        text = SHIPPED_ENVELOPE.read_text()
        shipped_sha = json.loads(text).get("model_sha256")
    except (OSError, ValueError):
        return  # not shipped or unreadable: the monitor measures it
    if shipped_sha == sha:
        target = model_path.with_name(model_path.name + ".envelope.json")
        tmp = target.with_name(target.name + ".tmp")
        tmp.write_text(text)
        tmp.replace(target)


def default_model_path() -> Path:
    """Where `monitor model build` writes and the monitor looks when no model is named:
    $WORKCELL_MONITOR_HOME/models, else ~/.cache/workcell-monitor/models."""
    import os

    home = os.environ.get("WORKCELL_MONITOR_HOME")
    base = Path(home) if home else Path.home() / ".cache" / "workcell-monitor"
    return base / "models" / "tiny-yolov3-synthetic.onnx"


# Default builds of earlier versions, size in bytes -> SHA-256: one found at the default place
# is built anew, so an upgrade runs this version's model (the 2026-11-28 build had a fixed
# 416x416 input: every frame ran in the full square, a third slower for 16:9 frames).
OLDER_BUILDS = {35_402_492: "cbe1e0a3ffb9eafee713d5d9b968ef6c21dfed732df1dada3e10865dcdd6ad89"}


def is_older_build(path: str | Path) -> bool:
    """The file is an earlier version's default build (its size is compared first: no other
    file is read)."""
    try:
        sha = OLDER_BUILDS.get(Path(path).stat().st_size)
        return sha is not None and hashlib.sha256(Path(path).read_bytes()).hexdigest() == sha
    except OSError:
        return False


def ensure_model(path: str | Path | None = None) -> Path:
    """The synthetic model, built when absent (takes about a second); at the default place
    also when it is an earlier version's build. A model at a path of the user's is never
    replaced."""
    target = Path(path) if path else default_model_path()
    if not target.is_file() or (path is None and is_older_build(target)):
        write_model(target)
    return target


def int8_ranges(p: SyntheticWeights | None = None) -> dict[str, tuple[float, int]]:
    """uint8 (scale, zero point) of the activations whose range the weights fix, for static
    quantization (``monitor.detector.quantize.QuantizeOptions.ranges``); the rest is calibrated.

    The gates are differences leaky(v) - leaky(v - 1) of two channels in one tensor. With
    1 / scale and 0.1 / scale whole numbers, both channels round by the same amount and the
    difference stays exact outside the gate's soft step; each range holds the channel's largest
    value so that neither side saturates (conv21's negative side may: a gate that is off stays
    off). Calibrated ranges do neither, and the int8 model then loses persons and fires on
    stickers.
    """
    p = p or SyntheticWeights()
    if p.row_mass_cap < p.min_mass + 1.0 / p.mass_gain:
        raise ValueError("row_mass_cap must be >= min_mass + 1 / mass_gain")
    unit = (1 / 250, 5)  # P and M in [0, 1], with a little room below zero
    pair = (1 / 80, 8)  # conv8: P, the capped-mass pair up to 3 / cap, the 0.1 constant
    if 3.0 / p.row_mass_cap > (255 - 8) / 80 or p.colour_gain * (2 + p.colour_threshold) > 15:
        raise ValueError("these weights exceed the analytic int8 ranges")
    head_max = p.mass_gain * (3 * p.row_mass_cap - p.min_mass)
    if head_max > 22.5 or p.presence_gain > 4.0:
        raise ValueError("these weights exceed the analytic int8 ranges")
    ranges: dict[str, tuple[float, int]] = {
        "images": (1 / 255, 0),  # the input is uint8 / 255: exact
        "conv0.out": (0.1, 160),  # z, z - 1 in [-16, 9.5]
        "conv0.act": (0.05, 40),  # leaky: [-2, 10.75]
        "pool1.out": (0.05, 40),
    }
    for name in ("conv2.out", "conv2.act", "pool3.out", "conv4.out", "conv4.act", "pool5.out",
                 "conv6.out", "conv6.act", "pool7.out"):
        ranges[name] = unit
    for name in ("conv8.out", "conv8.act", "pool9.out", "up.out", "route.out"):
        ranges[name] = pair
    ranges["conv21.out"] = (0.1, 30)  # [-3, 22.5]
    ranges["conv21.act"] = (0.1, 3)  # [-0.3, 25.2]
    return ranges
