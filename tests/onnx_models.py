"""Small ONNX models built in the tests: constant-output models whose outputs encode known boxes
(every output layout), a two-class model, and a YOLOv8-shaped export with its test frames."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

FRAME_W, FRAME_H, INPUT = 640, 480, 320
SCALE, PAD_X, PAD_Y = 0.5, 0.0, 40.0  # centred letterbox of 640x480 into 320x320
# persons in frame pixels (x1, y1, x2, y2), and one non-person that must be ignored
PERSONS = np.array([[100, 50, 200, 300], [400, 200, 520, 430]], np.float32)
OTHER = np.array([250, 100, 330, 180], np.float32)
WEAK = np.array([20, 300, 80, 420], np.float32)  # a person below the score threshold
C = 3  # classes: person, other, other


def to_input(box: np.ndarray, pad: tuple[float, float] = (PAD_X, PAD_Y)) -> np.ndarray:
    return box * SCALE + np.array([pad[0], pad[1], pad[0], pad[1]], np.float32)


def cxcywh(box: np.ndarray) -> list[float]:
    x1, y1, x2, y2 = box
    return [(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1]


def const_model(path: Path, outputs: dict[str, np.ndarray],
                inputs: dict[str, list[int | str]] | None = None,
                metadata: dict[str, str] | None = None,
                declared: dict[str, list[int | str]] | None = None) -> Path:
    """A model whose outputs are constants (plus 0 x the inputs, so every input is used).

    ``declared`` overrides an output's shape as written in the file (e.g. symbolic dims)."""
    declared = declared or {}
    inputs = inputs or {"images": [1, 3, INPUT, INPUT]}
    nodes, zero_terms = [], []
    for name in inputs:
        nodes.append(helper.make_node("ReduceSum", [name], [f"{name}_sum"], keepdims=0))
        nodes.append(helper.make_node("Mul", [f"{name}_sum", "zero"], [f"{name}_zero"]))
        zero_terms.append(f"{name}_zero")
    inits = [numpy_helper.from_array(np.array(0, np.float32), "zero")]
    outs = []
    for name, value in outputs.items():
        inits.append(numpy_helper.from_array(value, f"{name}_const"))
        if value.dtype == np.float32:
            last = f"{name}_const"
            for k, term in enumerate(zero_terms):
                nodes.append(helper.make_node("Add", [last, term], [f"{name}_{k}"]))
                last = f"{name}_{k}"
            nodes.append(helper.make_node("Identity", [last], [name]))
            outs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT,
                                                      declared.get(name, list(value.shape))))
        else:
            nodes.append(helper.make_node("Identity", [f"{name}_const"], [name]))
            outs.append(helper.make_tensor_value_info(name, TensorProto.INT32, list(value.shape)))
    graph = helper.make_graph(
        nodes, "const",
        [helper.make_tensor_value_info(n, TensorProto.FLOAT, s) for n, s in inputs.items()],
        outs, inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    for key, value in (metadata or {}).items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(model, path)
    return path


def shapeless_model(path: Path, name: str, value: np.ndarray) -> Path:
    """A model whose one output ``name`` is ``value`` reshaped by a shape computed from the
    input and declared without any shape: onnxruntime then reports its shape as ()."""
    zero = [helper.make_node("ReduceSum", ["images"], ["sum"], keepdims=0),
            helper.make_node("Mul", ["sum", "zero"], ["z"]),
            helper.make_node("Cast", ["z"], ["zi"], to=TensorProto.INT64),
            helper.make_node("Add", ["value", "z"], ["value_z"]),
            helper.make_node("Add", ["shape", "zi"], ["shape_z"]),
            helper.make_node("Reshape", ["value_z", "shape_z"], [name])]
    inits = [numpy_helper.from_array(np.array(0, np.float32), "zero"),
             numpy_helper.from_array(value, "value"),
             numpy_helper.from_array(np.array(value.shape, np.int64), "shape")]
    graph = helper.make_graph(
        zero, "shapeless",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, INPUT, INPUT])],
        [helper.make_tensor_value_info(name, TensorProto.FLOAT, None)], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, path)
    return path


def logit(p: float) -> float:
    return math.log(p / (1 - p))


def darknet_heads(grids: list[int], anchors, masks, nhwc: bool = False) -> dict[str, np.ndarray]:
    per = 5 + C
    heads = {g: np.zeros((3, per, g, g), np.float32) for g in grids}
    for h in heads.values():
        h[:, 4] = -12.0  # no object anywhere else
    coarse_first = sorted(grids)
    for k, box in enumerate([*PERSONS, OTHER]):
        g = coarse_first[k % len(grids)]  # spread boxes over heads
        rank = coarse_first.index(g)
        stride = INPUT / g
        cx, cy, w, h = cxcywh(to_input(box))
        gx, gy = int(cx // stride), int(cy // stride)
        slot = 1
        aw, ah = anchors[masks[rank][slot]]
        head = heads[g]
        head[slot, 0, gy, gx] = logit(cx / stride - gx)
        head[slot, 1, gy, gx] = logit(cy / stride - gy)
        head[slot, 2, gy, gx] = math.log(w / aw)
        head[slot, 3, gy, gx] = math.log(h / ah)
        head[slot, 4, gy, gx] = 6.0
        head[slot, 5, gy, gx] = 6.0 if k < len(PERSONS) else -6.0
        head[slot, 6, gy, gx] = -6.0 if k < len(PERSONS) else 6.0
    out = {}
    for i, g in enumerate(grids):
        t = heads[g].reshape(1, 3 * per, g, g)
        out[f"head{i}"] = np.ascontiguousarray(t.transpose(0, 2, 3, 1)) if nhwc else t
    return out


def two_class_model(path: Path) -> Path:
    """A fall detector: class 0 'Normal' (PERSONS[0]), class 1 'Fall' (PERSONS[1])."""
    rows = np.zeros((1, 20, 7), np.float32)
    rows[0, 0] = [*cxcywh(to_input(PERSONS[0])), 0.9, 0.95, 0.02]
    rows[0, 1] = [*cxcywh(to_input(PERSONS[1])), 0.9, 0.03, 0.9]
    return const_model(path, {"output0": rows}, metadata={"names": "{0: 'Normal', 1: 'Fall'}"})


def yolov8_like(path: Path, size: int = 256, seed: int = 0) -> Path:
    """A small graph shaped like an Ultralytics YOLOv8 export: SiLU convolutions, a box branch
    with a grid of anchor points, sigmoid class scores, output 1x84xN. Channel 0 carries
    "bright square here"; the other channels hold random weights like a trained model's."""
    rng = np.random.default_rng(seed)
    g = size // 8
    inits, nodes = [], []

    def init(name, array):
        inits.append(numpy_helper.from_array(np.asarray(array, np.float32), name))
        return name

    def silu(x, name):
        nodes.append(helper.make_node("Sigmoid", [x], [f"{name}.sig"], name=f"{name}.sig"))
        nodes.append(helper.make_node("Mul", [x, f"{name}.sig"], [f"{name}.act"],
                                      name=f"{name}.mul"))
        return f"{name}.act"

    w1 = rng.normal(0, 0.05, (16, 3, 8, 8))
    w1[0] = 1.0 / (3 * 64)
    b1 = rng.normal(0, 0.1, 16)
    b1[0] = -0.5
    nodes.append(helper.make_node("Conv", ["images", init("w1", w1), init("b1", b1)], ["c1"],
                                  name="c1", kernel_shape=[8, 8], strides=[8, 8]))
    a1 = silu("c1", "c1")
    w2 = rng.normal(0, 0.05, (16, 16, 3, 3))
    w2[0] = 0.0
    w2[0, 0, 1, 1] = 4.0
    nodes.append(helper.make_node("Conv", [a1, init("w2", w2), init("b2", np.zeros(16))], ["c2"],
                                  name="c2", kernel_shape=[3, 3], pads=[1, 1, 1, 1]))
    a2 = silu("c2", "c2")
    wc = rng.normal(0, 0.05, (80, 16, 1, 1))
    wc[0] = 0.0
    wc[0, 0] = 20.0
    nodes.append(helper.make_node("Conv", [a2, init("wc", wc), init("bc", np.full(80, -8.0))],
                                  ["cls.logit"], name="cls", kernel_shape=[1, 1]))
    nodes.append(helper.make_node("Sigmoid", ["cls.logit"], ["cls.score"], name="cls.sig"))
    nodes.append(helper.make_node("Reshape", ["cls.score", init("shape80", [1, 80, g * g])],
                                  ["cls.flat"], name="cls.flat"))
    inits[-1] = numpy_helper.from_array(np.array([1, 80, g * g], np.int64), "shape80")
    wb = np.zeros((2, 16, 1, 1))
    nodes.append(helper.make_node("Conv", [a2, init("wb", wb), init("bb", [16.0, 16.0])],
                                  ["wh"], name="box.wh", kernel_shape=[1, 1]))
    nodes.append(helper.make_node("Reshape", ["wh", "shape2"], ["wh.flat"], name="wh.flat"))
    inits.append(numpy_helper.from_array(np.array([1, 2, g * g], np.int64), "shape2"))
    yy, xx = np.mgrid[0:g, 0:g]
    grid = np.stack([xx.ravel(), yy.ravel()])[None] * 8.0 + 4.0
    nodes.append(helper.make_node("Concat", [init("anchor_points", grid), "wh.flat"], ["box"],
                                  axis=1, name="box"))
    nodes.append(helper.make_node("Concat", ["box", "cls.flat"], ["output0"], axis=1,
                                  name="head"))
    graph = helper.make_graph(
        nodes, "yolov8_like",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, size, size])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 84, g * g])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    entry = model.metadata_props.add()
    entry.key, entry.value = "names", str({i: ("person" if i == 0 else f"c{i}")
                                           for i in range(80)})
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def bright_squares(n: int, seed: int, size: int = 512) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(n):
        img = rng.normal(60, 6, (size, size, 3)).clip(0, 255).astype(np.uint8)
        for _ in range(int(rng.integers(1, 3))):
            s = int(rng.integers(90, 150))
            x, y = (int(v) for v in rng.integers(0, size - s, 2))
            img[y:y + s, x:x + s] = 235
        frames.append(img)
    return frames


def slow_on_marker(base: Path, path: Path, iterations: int, size: int = 512) -> Path:
    """``base`` (the synthetic model) made slow on some frames only: when the centre of its
    input is pure green (a marker square in the frame) an ``If`` branch runs ``iterations``
    chained MatMuls in a ``Loop`` before the outputs; any other frame costs nothing extra.
    The detections are the base model's either way (the marker adds exactly 0)."""
    model = onnx.load(base)
    g = model.graph

    def const(name: str, value) -> onnx.TensorProto:
        return numpy_helper.from_array(np.asarray(value), name)

    rng = np.random.default_rng(0)
    g.initializer.extend([
        const("mk.axes", np.array([2, 3], np.int64)),
        const("mk.hw_from", np.array([2], np.int64)),
        const("mk.hw_to", np.array([4], np.int64)),
        const("mk.two", np.array(2, np.int64)),
        const("mk.half", np.array(30, np.int64)),
        const("mk.weights", np.array([[[[-1.0]], [[1.0]], [[-1.0]]]], np.float32)),
        const("mk.threshold", np.array(0.8, np.float32)),
        const("mk.trips", np.array(iterations, np.int64)),
        const("mk.true", np.array(True)),
        const("mk.m0", (rng.standard_normal((size, size)) / math.sqrt(size)).astype(np.float32)),
        const("mk.w", (rng.standard_normal((size, size)) / math.sqrt(size)).astype(np.float32)),
        const("mk.zero", np.array(0.0, np.float32)),
    ])
    body = helper.make_graph(
        [helper.make_node("MatMul", ["m_in", "mk.w"], ["m_mul"]),
         helper.make_node("Tanh", ["m_mul"], ["m_out"]),
         helper.make_node("Identity", ["c_in"], ["c_out"])],
        "slow_body",
        [helper.make_tensor_value_info("i", TensorProto.INT64, []),
         helper.make_tensor_value_info("c_in", TensorProto.BOOL, []),
         helper.make_tensor_value_info("m_in", TensorProto.FLOAT, [size, size])],
        [helper.make_tensor_value_info("c_out", TensorProto.BOOL, []),
         helper.make_tensor_value_info("m_out", TensorProto.FLOAT, [size, size])])
    slow = helper.make_graph(
        [helper.make_node("Loop", ["mk.trips", "mk.true", "mk.m0"], ["mk.m_end"], body=body),
         helper.make_node("ReduceSum", ["mk.m_end"], ["mk.sum"], keepdims=0),
         helper.make_node("Mul", ["mk.sum", "mk.zero"], ["mk.slow_zero"])],
        "slow", [], [helper.make_tensor_value_info("mk.slow_zero", TensorProto.FLOAT, [])])
    fast = helper.make_graph(
        [helper.make_node("Identity", ["mk.zero"], ["mk.fast_zero"])],
        "fast", [], [helper.make_tensor_value_info("mk.fast_zero", TensorProto.FLOAT, [])])
    # green minus red minus blue, averaged over the centre (60x60 at the middle of whatever
    # input size the frame runs at): 1 for pure green, <= 0 otherwise
    g.node.extend([
        helper.make_node("Shape", ["images"], ["mk.shape"]),
        helper.make_node("Slice", ["mk.shape", "mk.hw_from", "mk.hw_to"], ["mk.hw"]),
        helper.make_node("Div", ["mk.hw", "mk.two"], ["mk.centre"]),
        helper.make_node("Sub", ["mk.centre", "mk.half"], ["mk.starts"]),
        helper.make_node("Add", ["mk.centre", "mk.half"], ["mk.ends"]),
        helper.make_node("Slice", ["images", "mk.starts", "mk.ends", "mk.axes"], ["mk.patch"]),
        helper.make_node("Conv", ["mk.patch", "mk.weights"], ["mk.green"]),
        helper.make_node("ReduceMean", ["mk.green"], ["mk.mean"], keepdims=0),
        helper.make_node("Greater", ["mk.mean", "mk.threshold"], ["mk.marked"]),
        helper.make_node("If", ["mk.marked"], ["mk.extra"], then_branch=slow, else_branch=fast),
    ])
    out13 = next(n for n in g.node if n.output[0] == "output_13")
    head13 = out13.input[0]
    g.node.remove(out13)  # re-added last, after the marker's 0: the nodes stay in order
    g.node.extend([helper.make_node("Add", [head13, "mk.extra"], ["mk.head13"]),
                   helper.make_node("Identity", ["mk.head13"], ["output_13"])])
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return path


def bf16_fragile(base: Path, path: Path, offset: float = 8000.0) -> Path:
    """``base`` (the synthetic model) with every output passed through two 1x1 identity
    convolutions that add ``offset`` and take it off again: exact in fp32, but a backend that
    stores the activation in between in bf16 (8 bits of mantissa: steps of 64 at 8000) rounds
    every logit to a multiple of 64 (to 0 here), and finds no person at all. A real model whose
    activations run large loses precision the same way, only less."""
    model = onnx.load(str(base))
    g = model.graph
    for out in g.output:
        name = out.name
        channels = next(d.dim_value for d in out.type.tensor_type.shape.dim[1:2])
        for node in g.node:
            node.output[:] = [name + ".raw" if o == name else o for o in node.output]
        eye = np.eye(channels, dtype=np.float32).reshape(channels, channels, 1, 1)
        g.initializer.extend([
            numpy_helper.from_array(eye, name + ".eye"),
            numpy_helper.from_array(np.full(channels, offset, np.float32), name + ".up"),
            numpy_helper.from_array(np.full(channels, -offset, np.float32), name + ".down")])
        g.node.extend([
            helper.make_node("Conv", [name + ".raw", name + ".eye", name + ".up"],
                             [name + ".big"]),
            helper.make_node("Relu", [name + ".big"], [name + ".kept"]),  # keeps the convs apart
            helper.make_node("Conv", [name + ".kept", name + ".eye", name + ".down"], [name])])
    onnx.save(model, str(path))
    return path
