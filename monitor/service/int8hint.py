"""At start: is there an int8 model beside the fp32 one whose agreement check passed, and how
much faster is it on this host? A log line and a ``int8`` status field; the model is never
switched automatically (the integrator decides, with the check's numbers in hand).

The agreement check (monitor/detector/quantize.py: persons found by fp32 and int8 on held-out
frames) is recorded beside the int8 file (``NAME.int8.onnx.check.json``, with the file's sha256) by
``monitor model quantize`` and ``monitor model build --int8``. An int8 file without a record of
a passed check (written with ``--force``, or replaced since) is never recommended.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from monitor.detector.quantize import Agreement, default_output


def record_path(int8: Path) -> Path:
    return int8.with_name(int8.name + ".check.json")


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_record(int8: Path, agreement: Agreement, min_agreement: float, passed: bool) -> Path:
    """Record the agreement check of the int8 file just written."""
    out = record_path(int8)
    out.write_text(json.dumps({
        "sha256": _sha256(int8), "passed": passed, "min_agreement": min_agreement,
        "agreement": round(agreement.agreement, 4), "frames": agreement.frames,
        "fp32_persons": agreement.fp32_persons, "missed": agreement.fp32_only,
        "fp32_ms": round(agreement.fp32_ms, 2), "int8_ms": round(agreement.int8_ms, 2)}) + "\n")
    return out


def check_passed(int8: Path) -> tuple[bool, str]:
    """Whether the recorded agreement check of ``int8`` passed, and what to say about it."""
    try:
        record = json.loads(record_path(int8).read_text())
    except FileNotFoundError:
        return False, (f"no record of its agreement check ({record_path(int8).name}): check it "
                       f"with 'monitor model quantize'")
    except (OSError, ValueError) as exc:
        return False, f"its check record is unreadable ({exc})"
    if record.get("sha256") != _sha256(int8):
        return False, "the file changed since its agreement check: check it again"
    if record.get("passed") is not True:
        return False, (f"its agreement check did not pass ({record.get('agreement')} < "
                       f"{record.get('min_agreement')}; written with --force)")
    return True, (f"its agreement check passed ({record.get('agreement')} on "
                  f"{record.get('frames')} held-out frames)")


@dataclass(frozen=True)
class Int8Hint:
    """The int8 file beside the model, timed against it on this host."""

    path: Path
    fp32_ms: float
    int8_ms: float
    passed: bool
    check: str

    @property
    def speedup(self) -> float:
        return self.fp32_ms / self.int8_ms if self.int8_ms > 0 else float("nan")

    def message(self) -> str:
        speed = (f"int8 is {self.speedup:.1f}x faster here ({self.fp32_ms:.1f} ms vs "
                 f"{self.int8_ms:.1f} ms a frame)")
        if self.passed:
            return f"{speed}; {self.check}: consider [model] path = \"{self.path}\""
        return f"{speed}, but not recommended: {self.check}"

    def to_dict(self) -> dict:
        return {"path": str(self.path), "fp32_ms": round(self.fp32_ms, 2),
                "int8_ms": round(self.int8_ms, 2), "speedup": round(self.speedup, 2),
                "recommended": self.passed, "check": self.check}


def int8_hint(model_path: Path, detect_fp32: Callable, open_int8: Callable[[Path], Callable],
              size: tuple[int, int], stopped: Callable[[], bool] = lambda: False
              ) -> Int8Hint | None:
    """Time the fp32 detector and the int8 file beside it (``open_int8(path)`` -> its detect)
    briefly on a frame of ``size``; None when there is none (or the model is int8 already)."""
    from monitor.service.capacity import measure_detect_s

    if model_path.name.endswith(".int8.onnx"):
        return None
    int8 = default_output(model_path)
    if not int8.is_file():
        return None
    passed, check = check_passed(int8)
    detect_int8 = open_int8(int8)
    # interleaved rounds: load that comes and goes hits both alike
    fp32_s = int8_s = 0.0
    for _ in range(2):
        a = measure_detect_s(detect_fp32, [size], runs=3, stopped=stopped)
        b = measure_detect_s(detect_int8, [size], runs=3, stopped=stopped)
        if a is None or b is None:
            return None
        fp32_s, int8_s = fp32_s + a, int8_s + b
    return Int8Hint(int8, fp32_s * 500.0, int8_s * 500.0, passed, check)
