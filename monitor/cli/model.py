"""`monitor model build | info | eval | quantize`: the synthetic model and any ONNX export."""

from __future__ import annotations

import argparse
import json
import sys
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
    build.add_argument("--int8", action="store_true",
                       help="also write the int8 model (NAME.int8.onnx beside it), checked "
                            "against fp32 on generated frames")
    build.set_defaults(func=cmd_build)

    info = sub.add_parser("info", help="layout, input size, classes and parameter count")
    info.add_argument("--model", type=Path, help="ONNX file (default: the synthetic model)")
    info.add_argument("--layout", help="force a layout instead of detecting it")
    info.add_argument("--config", type=Path,
                      help="monitor.toml: its [detector] settings (backend, precision, ...)")
    info.set_defaults(func=cmd_info)

    cb = sub.add_parser(
        "check-backend", help="check every backend and precision this host has against "
        "onnxruntime on your own frames",
        description="Runs your frames through onnxruntime on the CPU (the reference) and through "
                    "every other backend and precision this host has (OpenVINO fp32/bf16, "
                    "CUDA, ...), counts the persons they agree on as 'model quantize' does, and "
                    "records the result beside the model (MODEL.onnx.backends.json): monitor run "
                    "never chooses a backend that disagreed here. Exit 0 when all agree, 1 when "
                    "one is refused (see docs/models.md, Backends).")
    cb.add_argument("--frames", type=Path, required=True,
                    help="a directory of images or a video from your cameras, with persons")
    cb.add_argument("--model", type=Path, help="ONNX file (default: the config's, else the "
                    "synthetic model)")
    cb.add_argument("--config", type=Path, help="monitor.toml: its model and [detector] settings")
    cb.add_argument("--backend", help="check only this backend (default: every one here)")
    cb.add_argument("--precision", help="check only this precision (default: every one)")
    cb.add_argument("--min-agreement", type=float,
                    help="persons found by both / by either (default: "
                         "detector.backend_min_agreement, 0.98)")
    cb.add_argument("--max-frames", type=int, default=120,
                    help="frames read from --frames at most (spread over a video)")
    cb.set_defaults(func=cmd_check_backend)

    ev = sub.add_parser("eval", help="recall / precision on generated frames with ground truth")
    ev.add_argument("--model", type=Path, help="ONNX file (default: the synthetic model)")
    ev.add_argument("--frames", type=int, default=200, help="generated frames to score")
    ev.add_argument("--size", default="1920x1080", help="frame size WxH")
    ev.add_argument("--seed", type=int, default=0, help="random seed of the generated frames")
    ev.add_argument("--int8", action="store_true",
                    help="evaluate the synthetic model's int8 build (made when absent)")
    ev.set_defaults(func=cmd_eval)

    en = sub.add_parser(
        "envelope", help="measure the model's operating envelope (light, contrast, noise, "
        "blur) on its self-test figure and store it beside the model",
        description="Degrades the model's self-test image (the synthetic figure for the "
                    "synthetic model, detector.self_test_image for yours) in graded steps of "
                    "brightness, contrast, noise and blur, and stores the limits within which "
                    "the model still finds the person (MODEL.onnx.envelope.json); monitor run "
                    "STOPs when a camera's image leaves them (docs/health.md). Beside it, the "
                    "share of the figure the model needs in view, hidden from below and from "
                    "the side (MODEL.onnx.visible.json, docs/occlusion.md).")
    en.add_argument("--model", type=Path, help="ONNX file (default: the synthetic model)")
    en.add_argument("--config", type=Path,
                    help="monitor.toml: its model, detector self-test image and "
                         "health.envelope_min_recall")
    en.add_argument("--min-recall", type=float,
                    help="recall the envelope keeps (default: health.envelope_min_recall, 0.9)")
    en.add_argument("--print-only", action="store_true",
                    help="measure and print; do not store the sidecar file")
    en.set_defaults(func=cmd_envelope)

    q = sub.add_parser(
        "quantize", help="static int8 model calibrated on your frames, checked against fp32",
        description="Static int8 quantization (QDQ, per-channel weights) calibrated on frames "
                    "of your cell. Every 4th frame is held out: the int8 model's persons are "
                    "compared with the fp32 model's there, and the model is written only if "
                    "they agree (see docs/models-int8.md).")
    q.add_argument("model", type=Path, help="the fp32 ONNX model")
    q.add_argument("--frames", type=Path, required=True,
                   help="a directory of images or a video from your cameras, with persons")
    q.add_argument("--out", type=Path, help="output file (default: MODEL.int8.onnx beside it)")
    q.add_argument("--force", action="store_true",
                   help="write the model even when it disagrees with fp32")
    q.add_argument("--min-agreement", type=float, default=0.98,
                   help="persons found by both / by either on held-out frames (default 0.98)")
    q.add_argument("--method", default="minmax", choices=("minmax", "entropy", "percentile"),
                   help="calibration method (default minmax, the measured best)")
    q.add_argument("--quantize-heads", action="store_true",
                   help="quantize the output heads too (default: keep them in float)")
    q.add_argument("--max-frames", type=int, default=120,
                   help="frames read from --frames at most (spread over a video)")
    q.set_defaults(func=cmd_quantize)


def cmd_build(args: argparse.Namespace) -> int:
    from monitor.models import synthetic

    out = args.out or synthetic.default_model_path()
    if args.input_size % 32 or not 64 <= args.input_size <= 1024:
        raise MonitorError(f"--input-size {args.input_size} is not a multiple of 32 in 64..1024")
    from monitor.progress import Steps

    steps = Steps(["fp32 model"] + (["int8 model", "check"] if args.int8 else []),
                  "model build")
    steps.start("building the fp32 model")
    digest = synthetic.write_model(out, input_size=args.input_size)
    steps.done()
    print(f"wrote {out} (sha256 {digest})")
    if args.int8:
        int8, agreement = build_int8(out, steps)
        print(agreement.table())
        print(f"wrote {int8}")
    return 0


def build_int8(fp32: Path, steps=None):
    """The synthetic model's int8 file beside ``fp32``: analytic ranges, calibration on
    generated frames, then checked on other generated frames (refused below 0.98)."""
    from monitor.detector import Detector, quantize
    from monitor.models import synthetic
    from monitor.progress import progress
    from monitor.scene import random_frames

    out = quantize.default_output(fp32)
    staged = out.with_name(out.stem + ".unchecked.onnx")
    if steps:
        steps.start("calibrating the int8 model")
    calib = [f for f, _ in random_frames(24, seed=1000, size=(1920, 1080))]
    options = quantize.QuantizeOptions(ranges=synthetic.int8_ranges())
    quantize.quantize_model(fp32, staged, calib, options, wrap=_wrap(progress))
    if steps:
        steps.done()
        steps.start("checking int8 against fp32")
    held = [f for f, t in random_frames(24, seed=2000, size=(1920, 1080)) if t.persons]
    agreement = quantize.compare(Detector(fp32), Detector(staged), held, wrap=_wrap(progress))
    why = quantize.check_agreement(agreement, 0.98)
    if why:
        staged.unlink(missing_ok=True)
        raise quantize.QuantizeRefused(f"int8 synthetic model not written: {why}")
    staged.replace(out)
    from monitor.service.int8hint import write_record

    write_record(out, agreement, 0.98, True)  # monitor run recommends only a checked int8
    if steps:
        steps.done()
    return out, agreement


def _wrap(progress):
    return lambda items, total, desc: progress(items, total, desc)


def _detector(model: Path | None, layout: str | None = None, int8: bool = False):
    from monitor.cli.run import ensure_model
    from monitor.detector import Detector, DetectorConfig, quantize

    path = model if model else ensure_model()
    if int8 and model is None:
        int8_path = quantize.default_output(path)
        if not int8_path.is_file():
            build_int8(path)
        path = int8_path
    return Detector(path, DetectorConfig(layout=layout))


def _configured(model: Path | None, config_path: Path | None):
    """The model and [detector] settings of ``--config`` (the model given wins), the
    synthetic model when neither names one."""
    from monitor.detector import DetectorConfig

    detector_config = DetectorConfig()
    if config_path is not None:
        from monitor.config import load_config

        config = load_config(config_path)
        detector_config = config.detector
        model = model or (Path(config.model.path) if config.model.path else None)
    if model is None:
        from monitor.cli.run import ensure_model

        model = ensure_model()
    return model, detector_config


def cmd_info(args: argparse.Namespace) -> int:
    import dataclasses

    from monitor.detector import describe
    from monitor.detector.choice import open_detector

    model, config = _configured(args.model, args.config)
    if args.layout:
        config = dataclasses.replace(config, layout=args.layout)
    detector, choice = open_detector(
        model, config, progress=lambda text: print(f"{text} ...", file=sys.stderr))
    info = describe(detector)
    info["backend"] = choice.line().removeprefix("detector backend ")
    info = {"host": choice.host or "?", **info}
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
    from monitor.scene import random_frames
    from monitor.scene.accuracy import Accuracy, cell_tolerance_px, score_frame

    detector = _detector(args.model, int8=args.int8)
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


def cmd_envelope(args: argparse.Namespace) -> int:
    from monitor.detector import Detector, DetectorConfig, visible
    from monitor.detector import envelope as env
    from monitor.health import HealthConfig

    detector_config, health = DetectorConfig(), HealthConfig()
    model = args.model
    if args.config is not None:
        from monitor.config import load_config

        config = load_config(args.config)
        detector_config, health = config.detector, config.health
        model = model or (Path(config.model.path) if config.model.path else None)
    min_recall = health.envelope_min_recall if args.min_recall is None else args.min_recall
    if not 0.5 <= min_recall <= 1.0:
        raise MonitorError(f"--min-recall {min_recall} is not in 0.5 .. 1")
    if model is None:
        from monitor.cli.run import ensure_model

        model = ensure_model()
    detector = Detector(model, detector_config)
    if detector.self_test_case is None:
        raise MonitorError(f"{model}: no self-test image to measure on: set "
                           "detector.self_test_image and self_test_box in the --config "
                           "(docs/models.md)")
    envelope = env.for_detector(detector, min_recall, store=not args.print_only,
                                progress=lambda axis: print(f"measuring {axis} ...",
                                                            file=sys.stderr))
    print(envelope.table())
    # beside it: how much of a person the model needs in view (docs/occlusion.md)
    needed = visible.for_detector(detector, min_recall, store=not args.print_only)
    if needed is not None:
        print(needed.table())
    if not args.print_only:  # measured with the backend [detector] names (auto: onnxruntime)
        print(f"wrote {env.sidecar_path(model, env.backend_tag(detector))}")
        print(f"wrote {visible.sidecar_path(model)}")
    return 0


def cmd_quantize(args: argparse.Namespace) -> int:
    from monitor.detector import Detector, quantize
    from monitor.errors import InputError
    from monitor.progress import Steps, progress

    model = args.model
    out = args.out or quantize.default_output(model)
    if out.resolve() == model.resolve():
        raise InputError(f"--out {out} is the input model: choose another file")
    if args.max_frames < quantize.MIN_FRAMES:
        raise InputError(f"--max-frames must be at least {quantize.MIN_FRAMES}")
    fp32 = Detector(model)  # ModelError (one line) when MODEL is not a usable model
    steps = Steps(["reading frames", "quantizing", "comparing"], "model quantize")
    steps.start("reading frames")
    frames = quantize.read_frames(args.frames, args.max_frames)
    steps.done()
    calib, held = quantize.split_frames(frames)
    print(f"{len(frames)} frames: {len(calib)} for calibration, {len(held)} held out",
          file=sys.stderr)
    options = quantize.QuantizeOptions(method=args.method,
                                       keep_float=() if args.quantize_heads else None)
    staged = out.with_name(out.stem + ".unchecked.onnx")
    wrap = _wrap(progress)
    try:
        steps.start("calibrating and quantizing")
        quantize.quantize_model(model, staged, calib, options, wrap=wrap)
        steps.done()
        steps.start("comparing int8 with fp32")
        agreement = quantize.compare(fp32, Detector(staged), held, wrap=wrap)
        steps.done()
        print(agreement.table())
        why = quantize.check_agreement(agreement, args.min_agreement)
        if why and not args.force:
            raise quantize.QuantizeRefused(f"int8 model not written: {why} (--force writes it)")
        staged.replace(out)
        from monitor.service.int8hint import write_record

        # monitor run recommends only an int8 whose check passed (a forced one: never)
        write_record(out, agreement, args.min_agreement, why is None)
    finally:
        steps.close()
        staged.unlink(missing_ok=True)
    if why:
        print(f"warning: written anyway (--force): {why}", file=sys.stderr)
    print(f"wrote {out}")
    return 0


def cmd_check_backend(args: argparse.Namespace) -> int:
    import dataclasses

    from monitor.detector import quantize
    from monitor.detector.choice import check_frames
    from monitor.progress import progress

    model, config = _configured(args.model, args.config)
    changes = {k: v for k, v in (("backend", args.backend), ("precision", args.precision),
                                 ("backend_min_agreement", args.min_agreement))
               if v is not None}
    if changes:
        config = dataclasses.replace(config, **changes)  # validated: one line when bad
    frames = quantize.read_frames(args.frames, args.max_frames)
    print(f"{len(frames)} frames from {args.frames}", file=sys.stderr)
    trials = check_frames(model, config, frames, wrap=_wrap(progress))
    if not trials:
        print("only onnxruntime (the reference) runs the model here: nothing to check")
        return 0
    print("| backend | precision | persons onnxruntime / it | found by both | missed | extra "
          "| agreement | box IoU min | inference ms onnxruntime / it | verdict |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for t in trials:
        a = t.agreement
        if a is None:
            print(f"| {t.candidate.backend} | {t.candidate.precision} | - | - | - | - | - | - "
                  f"| - | not usable |")
            continue
        print(f"| {t.candidate.backend} | {t.candidate.precision} | {a.fp32_persons} / "
              f"{a.int8_persons} | {a.both} | {a.fp32_only} | {a.int8_only} | "
              f"{a.agreement:.3f} | {a.min_iou:.3f} | {a.fp32_ms:.1f} / {a.int8_ms:.1f} | "
              f"{'refused' if t.refused else 'agrees'} |")
    refused = [t for t in trials if t.refused]
    for t in refused:
        print(f"refused: {t.candidate.label}: {t.refused}", file=sys.stderr)
    return 1 if refused else 0
