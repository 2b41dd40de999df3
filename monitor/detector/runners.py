"""The backend seam: "run this model on this tensor", whatever runtime does it.

A ``Runner`` has the model's input and output ports (names and shapes as the file declares
them), its metadata, and ``run(feeds) -> outputs`` (every output, in the file's order). The
detector, the self-test, the envelope, the in-place check, quantize's comparison and the capacity
check all run the model through one; nothing else in the monitor imports a runtime.

==========================  ============================================  =====================
backend                     runtime and device                            precisions
==========================  ============================================  =====================
``onnxruntime``             onnxruntime, CPU execution provider (core)    the model's own
``onnxruntime-cuda``        onnxruntime-gpu, CUDA execution provider      the model's own
``onnxruntime-tensorrt``    onnxruntime-gpu, TensorRT execution provider  the model's own
``onnxruntime-openvino``    onnxruntime-openvino, OpenVINO EP             the model's own
``openvino``                OpenVINO runtime on the CPU (``[openvino]``)  fp32, bf16 (int8 QDQ)
``openvino-gpu``            OpenVINO runtime on its GPU device            fp32, fp16 (int8 QDQ)
==========================  ============================================  =====================

The model's own precision is ``fp32``, or ``int8`` for a QDQ model (``monitor model quantize``);
an int8 model runs int8 on every backend. ``onnxruntime`` on the CPU is the reference every
other backend and precision is checked against (``monitor.detector.choice``). A backend whose
package is not installed is one line saying what to install (``BackendUnavailable``).
"""

from __future__ import annotations

import re
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from monitor.errors import ModelError

REFERENCE = "onnxruntime"
ORT_PROVIDERS = {
    "onnxruntime": ("CPUExecutionProvider",),
    "onnxruntime-cuda": ("CUDAExecutionProvider", "CPUExecutionProvider"),
    "onnxruntime-tensorrt": ("TensorrtExecutionProvider", "CUDAExecutionProvider",
                             "CPUExecutionProvider"),
    "onnxruntime-openvino": ("OpenVINOExecutionProvider", "CPUExecutionProvider"),
}
ORT_PACKAGES = {"onnxruntime-cuda": "onnxruntime-gpu", "onnxruntime-tensorrt": "onnxruntime-gpu",
                "onnxruntime-openvino": "onnxruntime-openvino"}
OV_DEVICES = {"openvino": "CPU", "openvino-gpu": "GPU"}
BACKENDS = (*ORT_PROVIDERS, *OV_DEVICES)
PRECISIONS = ("fp32", "bf16", "fp16", "int8")
# OpenVINO's inference precision hint per precision (an int8 QDQ model runs its quantized
# layers in int8 whatever the hint; the rest in f32)
_OV_HINT = {"fp32": "f32", "bf16": "bf16", "fp16": "f16", "int8": "f32"}
QDQ_OPS = {"QuantizeLinear", "DequantizeLinear", "QLinearConv", "QLinearMatMul", "ConvInteger",
           "MatMulInteger"}
OPENVINO_MISSING = ("backend 'openvino' needs the OpenVINO runtime, which is not installed: "
                    "pip install 'workcell-monitor[openvino]' (or set [detector] backend = "
                    "\"auto\" or \"onnxruntime\")")


class BackendUnavailable(ModelError):
    """The backend's package, execution provider or device is not on this host."""


@dataclass(frozen=True)
class Port:
    """One model input or output: its name and declared shape (None: a dynamic dimension)."""

    name: str
    shape: tuple[int | None, ...]


@dataclass(frozen=True)
class Candidate:
    """A backend and the precision it runs the model at."""

    backend: str
    precision: str

    @property
    def label(self) -> str:
        return f"{self.backend} {self.precision}"

    @classmethod
    def parse(cls, label: str) -> Candidate:
        backend, _, precision = label.partition(" ")
        return cls(backend, precision)


class Runner(Protocol):
    """Runs one model: ``run(feeds)`` -> every output, in the model's order."""

    candidate: Candidate
    inputs: tuple[Port, ...]
    outputs: tuple[Port, ...]
    metadata: dict[str, str]

    def run(self, feeds: Mapping[str, np.ndarray]) -> list[np.ndarray]: ...


@dataclass(frozen=True)
class ModelFacts:
    """What the model file says before any runtime opens it: metadata and whether it is a
    quantized (QDQ) model."""

    metadata: dict[str, str]
    quantized: bool

    @property
    def precision(self) -> str:
        """The model's own precision: what the reference runs it at."""
        return "int8" if self.quantized else "fp32"


def model_facts(model_path: str | Path) -> ModelFacts:
    """Metadata and quantization of an ONNX file (the graph only; no weights loaded twice)."""
    import onnx

    path = Path(model_path)
    if not path.is_file():
        raise ModelError(f"model file not found: {path}")
    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # onnx raises DecodeError and friends for a corrupt file
        raise ModelError(f"cannot load model {path}: {runtime_message(exc)}") from None
    meta = {p.key: p.value for p in model.metadata_props}
    quantized = any(n.op_type in QDQ_OPS for n in model.graph.node)
    return ModelFacts(meta, quantized)


def openvino_installed() -> bool:
    try:
        import openvino  # noqa: F401
    except ImportError:
        return False
    return True


def runtime_versions() -> dict[str, str]:
    """The installed runtimes' versions (a new version may compute differently: the choice
    is measured anew)."""
    import onnxruntime as ort

    versions = {"onnxruntime": ort.__version__}
    if openvino_installed():
        import openvino as ov

        versions["openvino"] = ov.get_version()
    return versions


def available(facts: ModelFacts) -> list[Candidate]:
    """Every backend and precision this host can run the model at, the reference first."""
    import onnxruntime as ort

    own = facts.precision
    found = [Candidate(REFERENCE, own)]
    providers = set(ort.get_available_providers())
    for backend, wanted in ORT_PROVIDERS.items():
        if backend != REFERENCE and wanted[0] in providers:
            found.append(Candidate(backend, own))
    if openvino_installed():
        import openvino as ov

        core = ov.Core()
        for backend, device in OV_DEVICES.items():
            if not any(d.split(".")[0] == device for d in core.available_devices):
                continue
            found.append(Candidate(backend, own))
            if own == "fp32":
                caps = set(core.get_property(device, "OPTIMIZATION_CAPABILITIES"))
                for precision, cap in (("bf16", "BF16"), ("fp16", "FP16")):
                    if cap in caps and (device == "CPU") == (precision == "bf16"):
                        found.append(Candidate(backend, precision))
    return found


def open_runner(model_path: str | Path, candidate: Candidate, threads: int,
                spin_wait: bool = False, facts: ModelFacts | None = None) -> Runner:
    """A runner of ``candidate`` for the model (precision "auto": the model's own);
    ModelError on a bad file, BackendUnavailable when this host cannot run it."""
    path = Path(model_path)
    if not path.is_file():
        raise ModelError(f"model file not found: {path}")
    if candidate.backend not in BACKENDS:
        raise BackendUnavailable(f"unknown backend {candidate.backend!r}; known: "
                                 f"{', '.join(BACKENDS)}")
    if candidate.backend in ORT_PROVIDERS:
        return OnnxRuntimeRunner(path, candidate, threads, spin_wait, facts)
    return OpenVinoRunner(path, candidate, threads, facts)


class OnnxRuntimeRunner:
    """onnxruntime with full graph optimisation on its CPU provider or the backend's execution
    provider; ``session.run`` is safe from several threads."""

    def __init__(self, path: Path, candidate: Candidate, threads: int, spin_wait: bool,
                 facts: ModelFacts | None = None) -> None:
        import onnxruntime as ort

        providers = ORT_PROVIDERS[candidate.backend]
        if providers[0] not in ort.get_available_providers():
            package = ORT_PACKAGES.get(candidate.backend, "onnxruntime")
            raise BackendUnavailable(
                f"backend {candidate.backend!r} needs onnxruntime's {providers[0]}, which this "
                f"installation lacks (it comes with the {package} package)")
        opts = ort.SessionOptions()
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.intra_op_num_threads = max(1, threads)
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        opts.add_session_config_entry("session.intra_op.allow_spinning",
                                      "1" if spin_wait else "0")
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=list(providers))
        except Exception as exc:  # onnxruntime raises its own exception types for corrupt files
            raise ModelError(f"cannot load model {path}: {runtime_message(exc)}") from None
        if providers[0] not in self.session.get_providers():  # fell back to the CPU
            raise BackendUnavailable(f"backend {candidate.backend!r}: onnxruntime could not "
                                     f"start {providers[0]} on this host")
        facts = facts or model_facts(path)
        if candidate.precision not in ("auto", facts.precision):
            raise BackendUnavailable(f"backend {candidate.backend!r} runs the model at its own "
                                     f"precision ({facts.precision}), not "
                                     f"{candidate.precision}")
        self.candidate = Candidate(candidate.backend, facts.precision)
        self.inputs = tuple(Port(i.name, _dims(i.shape)) for i in self.session.get_inputs())
        self.outputs = tuple(Port(o.name, _dims(o.shape)) for o in self.session.get_outputs())
        self.metadata = dict(self.session.get_modelmeta().custom_metadata_map or {})
        self._names = [o.name for o in self.outputs]

    def run(self, feeds: Mapping[str, np.ndarray]) -> list[np.ndarray]:
        return self.session.run(self._names, dict(feeds))


class OpenVinoRunner:
    """The OpenVINO runtime: the model read once, compiled once per input shape (a camera's
    frames all have one) with one infer request each, reused for every frame. One run at a
    time per request (the self-test may call from another thread), and the outputs copied out
    of the request's buffers, which the next run overwrites."""

    def __init__(self, path: Path, candidate: Candidate, threads: int,
                 facts: ModelFacts | None = None) -> None:
        try:
            import openvino as ov
        except ImportError:
            raise BackendUnavailable(OPENVINO_MISSING) from None
        facts = facts or model_facts(path)
        device = OV_DEVICES[candidate.backend]
        self._core = ov.Core()
        if not any(d.split(".")[0] == device for d in self._core.available_devices):
            raise BackendUnavailable(f"backend {candidate.backend!r}: OpenVINO finds no {device} "
                                     f"device on this host (it has "
                                     f"{', '.join(self._core.available_devices) or 'none'})")
        precision = candidate.precision
        if precision == "auto":
            precision = facts.precision
        if facts.quantized and precision != "int8":
            raise BackendUnavailable(f"the model is int8 (QDQ): backend {candidate.backend!r} "
                                     f"runs it at int8, not {precision}")
        if not facts.quantized and precision not in ("fp32", "bf16", "fp16"):
            raise BackendUnavailable(f"precision {precision!r} is for int8 (QDQ) models; this "
                                     f"one is fp32")
        if precision in ("bf16", "fp16"):
            caps = set(self._core.get_property(device, "OPTIMIZATION_CAPABILITIES"))
            if precision.upper() not in caps:
                raise BackendUnavailable(f"backend {candidate.backend!r}: this {device} has no "
                                         f"{precision} support (it offers "
                                         f"{', '.join(sorted(caps))})")
        try:
            self._model = self._core.read_model(str(path))
        except Exception as exc:  # OpenVINO's own exception types
            raise ModelError(f"cannot load model {path} in OpenVINO: "
                             f"{runtime_message(exc)}") from None
        self._device = device
        self._config = {"INFERENCE_PRECISION_HINT": _OV_HINT[precision],
                        "PERFORMANCE_HINT": "LATENCY"}
        if device == "CPU":
            self._config["INFERENCE_NUM_THREADS"] = max(1, threads)
        self.candidate = Candidate(candidate.backend, precision)
        self.inputs = tuple(Port(_ov_name(p, f"input{k}"), _ov_dims(p.get_partial_shape()))
                            for k, p in enumerate(self._model.inputs))
        self.outputs = tuple(Port(_ov_name(p, f"output{k}"), _ov_dims(p.get_partial_shape()))
                             for k, p in enumerate(self._model.outputs))
        self.metadata = dict(facts.metadata)
        self._static = all(d is not None for p in self.inputs for d in p.shape)
        self._requests: dict[tuple, tuple[object, threading.Lock]] = {}
        self._lock = threading.Lock()
        if self._static:
            self._request(())

    def _request(self, key: tuple) -> tuple[object, threading.Lock]:
        """The compiled model and infer request of one set of input shapes (``()``: the
        model's own static shapes)."""
        found = self._requests.get(key)
        if found is not None:
            return found
        with self._lock:
            found = self._requests.get(key)
            if found is None:
                model = self._model
                if key:  # a static copy at these shapes: OpenVINO plans it once, like ONNX's
                    model = self._model.clone()
                    model.reshape(dict(zip([p.name for p in self.inputs], key, strict=True)))
                try:
                    compiled = self._core.compile_model(model, self._device, self._config)
                except Exception as exc:  # OpenVINO's own exception types
                    raise ModelError(f"OpenVINO cannot compile the model for {self._device}: "
                                     f"{runtime_message(exc)}") from None
                found = (compiled.create_infer_request(), threading.Lock())
                self._requests[key] = found
        return found

    def run(self, feeds: Mapping[str, np.ndarray]) -> list[np.ndarray]:
        arrays = [np.ascontiguousarray(feeds[p.name]) for p in self.inputs]
        key = () if self._static else tuple(tuple(a.shape) for a in arrays)
        request, lock = self._request(key)
        with lock:
            result = request.infer(arrays)
            return [np.array(result[k], copy=True) for k in range(len(self.outputs))]


def _dims(shape) -> tuple[int | None, ...]:
    return tuple(d if isinstance(d, int) and d > 0 else None for d in (shape or ()))


def _ov_dims(shape) -> tuple[int | None, ...]:
    if shape.rank.is_dynamic:
        return ()
    return tuple(d.get_length() if d.is_static else None for d in shape)


def _ov_name(port, default: str) -> str:
    try:
        return port.get_any_name()
    except RuntimeError:  # a tensor without a name
        return default


def runtime_message(exc: BaseException) -> str:
    """A runtime's message without its status-code prefix: '[ONNXRuntimeError] : 7 :
    INVALID_PROTOBUF : Load model from m.onnx failed:Protobuf parsing failed.' -> 'Protobuf
    parsing failed.'"""
    text = (str(exc).strip().splitlines() or [""])[0]
    text = re.sub(r"^\[ONNXRuntimeError\]\s*:\s*\d+\s*:\s*\w+\s*:\s*", "", text)
    text = re.sub(r"^Load model from .*? failed:\s*", "", text)
    text = re.sub(r"^Exception from src/.*?:\d+:\s*", "", text)
    return text.strip()[:200] or "unreadable file"
