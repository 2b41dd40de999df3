"""Opening an ONNX model in onnxruntime."""

from __future__ import annotations

import re
from pathlib import Path

from monitor.errors import ModelError


def open_session(model_path: str | Path, threads: int, spin_wait: bool = False):
    """An onnxruntime CPU session with full graph optimisation; ModelError on a bad file."""
    import onnxruntime as ort

    path = Path(model_path)
    if not path.is_file():
        raise ModelError(f"model file not found: {path}")
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.intra_op_num_threads = max(1, threads)
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if spin_wait else "0")
    try:
        return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types for corrupt files
        raise ModelError(f"cannot load model {path}: {runtime_message(exc)}") from None


def runtime_message(exc: BaseException) -> str:
    """onnxruntime's message without its status-code prefix: '[ONNXRuntimeError] : 7 :
    INVALID_PROTOBUF : Load model from m.onnx failed:Protobuf parsing failed.' -> 'Protobuf
    parsing failed.'"""
    text = (str(exc).strip().splitlines() or [""])[0]
    text = re.sub(r"^\[ONNXRuntimeError\]\s*:\s*\d+\s*:\s*\w+\s*:\s*", "", text)
    text = re.sub(r"^Load model from .*? failed:\s*", "", text)
    return text.strip()[:200] or "unreadable file"
