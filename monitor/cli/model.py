"""`monitor model build | info | eval`: the synthetic model and any ONNX export."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from monitor.errors import MonitorError


def register(subparsers: argparse._SubParsersAction) -> None:
    model = subparsers.add_parser("model", help="build, inspect or evaluate detector models")
    sub = model.add_subparsers(dest="model_command", metavar="ACTION", required=True)

    build = sub.add_parser("build", help="build the synthetic tiny-YOLOv3 model (deterministic)")
    build.add_argument("--out", type=Path, help="output .onnx (default: the model cache)")
    build.add_argument("--input-size", type=int, default=416,
                       help="model input size in pixels, a multiple of 32 (416 is the classic "
                       "tiny-YOLOv3 size; 320 or 256 are faster, worse on small persons)")
    build.set_defaults(func=cmd_build)

    info = sub.add_parser("info", help="layout, input size, classes and parameter count")
    info.add_argument("--model", type=Path, help="ONNX file (default: the synthetic model)")
    info.add_argument("--layout", help="force a layout instead of detecting it")
    info.set_defaults(func=cmd_info)

    ev = sub.add_parser("eval", help="recall / precision on generated frames with ground truth")
    ev.add_argument("--model", type=Path, help="ONNX file (default: the synthetic model)")
    ev.add_argument("--frames", type=int, default=200, help="generated frames to score")
    ev.add_argument("--size", default="1920x1080", help="frame size WxH")
    ev.add_argument("--seed", type=int, default=0, help="random seed of the generated frames")
    ev.set_defaults(func=cmd_eval)


def cmd_build(args: argparse.Namespace) -> int:
    from monitor.models import synthetic

    out = args.out or synthetic.default_model_path()
    if args.input_size % 32 or not 64 <= args.input_size <= 1024:
        raise MonitorError(f"--input-size {args.input_size} is not a multiple of 32 in 64..1024")
    digest = synthetic.write_model(out, input_size=args.input_size)
    print(f"wrote {out} (sha256 {digest})")
    return 0


def _detector(model: Path | None, layout: str | None = None):
    from monitor.detector import Detector, DetectorConfig
    from monitor.models import synthetic

    path = model if model else synthetic.ensure_model()
    return Detector(path, DetectorConfig(layout=layout))


def cmd_info(args: argparse.Namespace) -> int:
    from monitor.detector import describe

    info = describe(_detector(args.model, args.layout))
    width = max(len(k) for k in info)
    for key, value in info.items():
        print(f"{key:<{width}}  {value}")
    return 0


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise MonitorError(f"size {text!r} is not WxH (e.g. 1920x1080)") from None
    if w < 32 or h < 32:
        raise MonitorError(f"size {text!r} is too small")
    return w, h


def cmd_eval(args: argparse.Namespace) -> int:
    from monitor.accuracy import Accuracy, cell_tolerance_px, score_frame
    from monitor.scene import random_frames

    detector = _detector(args.model)
    size = parse_size(args.size)
    tolerance = cell_tolerance_px(size, detector.layout.input_width)
    acc = Accuracy()
    start = time.perf_counter()
    for image, truth in random_frames(args.frames, seed=args.seed, size=size):
        score_frame(detector.detect(image).boxes_px, truth, tolerance, acc)
    print(json.dumps({
        "frames": args.frames, "size": args.size, "seed": args.seed, "persons": acc.persons,
        "recall": round(acc.recall, 4), "precision": round(acc.precision, 4),
        "mean_iou": round(acc.mean_iou, 3), "one_box_per_person": round(acc.one_box_share, 4),
        "distractor_hits": acc.distractor_hits, "tolerance_px": round(tolerance, 1),
        "seconds": round(time.perf_counter() - start, 1)}))
    return 0
