"""`monitor detect IMAGE_OR_VIDEO`: persons per frame as JSON lines, optional annotated output."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import cv2
import numpy as np

from monitor.detector.layouts import LAYOUTS
from monitor.errors import InputError
from monitor.frames import IMAGE_SUFFIXES


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("detect", help="detect persons in an image or video (JSON lines)")
    p.add_argument("input", type=Path, help="image (.png, .jpg, ...) or video file")
    p.add_argument("--model", type=Path,
                   help="ONNX model (default: the synthetic model, built on first use)")
    p.add_argument("--out", type=Path,
                   help="also write an annotated copy: .png/.jpg for images, .mp4 for video")
    p.add_argument("--threshold", type=float, default=0.5,
                   help="score threshold in [0, 1]: lower finds more persons, and more false "
                   "stops")
    p.add_argument("--threads", type=int, default=2, help="inference threads")
    p.add_argument("--layout", choices=LAYOUTS,
                   help="force a model output layout (default: detected from the model)")
    p.add_argument("--person-classes", metavar="LIST",
                   help="comma-separated class names or ids that are persons, e.g. "
                   "'Normal,Fall' (default: every class named person, else class 0)")
    p.set_defaults(func=cmd_detect)


def draw_persons(image: np.ndarray, boxes: np.ndarray, scores: np.ndarray) -> np.ndarray:
    out = image.copy()
    for (x1, y1, x2, y2), s in zip(boxes, scores, strict=True):
        if not np.isfinite([x1, y1, x2, y2, s]).all():
            continue  # cannot be drawn (the detector refuses such boxes anyway)
        cv2.rectangle(out, (int(x1), int(y1)), (int(x2) - 1, int(y2) - 1), (0, 255, 0), 2)
        cv2.putText(out, f"person {s:.2f}", (int(x1), max(12, int(y1) - 4)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 0), 1, cv2.LINE_AA)
    return out


def _num(value: float, digits: int) -> float | None:
    """JSON has no NaN or Infinity: a non-finite number is written as null."""
    value = float(value)
    return round(value, digits) if math.isfinite(value) else None


def _line(index: int, time_s: float, persons) -> str:
    return json.dumps({
        "frame": index, "time_s": _num(time_s, 4),
        "persons": [{"box_px": [_num(v, 1) for v in b], "score": _num(s, 3)}
                    for b, s in zip(persons.boxes_px, persons.scores, strict=True)]},
        allow_nan=False)


def parse_person_classes(text: str | None) -> tuple[str | int, ...] | None:
    """'Normal, Fall' or '0,1' -> ('Normal', 'Fall') or (0, 1)."""
    if text is None:
        return None
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise InputError("--person-classes: give class names or ids, comma-separated")
    return tuple(int(t) if t.isdigit() else t for t in items)


def cmd_detect(args: argparse.Namespace) -> int:
    from monitor.detector import Detector, DetectorConfig
    from monitor.frames import VideoFileReader
    from monitor.models import synthetic

    if not args.input.exists():
        raise InputError(f"{args.input}: no such file")
    model = args.model if args.model else synthetic.ensure_model()
    detector = Detector(model, DetectorConfig(
        score_threshold=args.threshold, threads=args.threads, layout=args.layout,
        person_classes=parse_person_classes(args.person_classes)))
    if args.input.suffix.lower() in IMAGE_SUFFIXES:
        image = cv2.imread(str(args.input), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(f"{args.input}: cannot read the image (corrupt or unknown format)")
        persons = detector.detect(image)
        print(_line(0, 0.0, persons))
        annotated = draw_persons(image, persons.boxes_px, persons.scores)
        if args.out and not cv2.imwrite(str(args.out), annotated):
            raise InputError(f"{args.out}: cannot write the image")
        return 0
    writer = None
    reader = VideoFileReader(args.input, "video")
    try:
        reader.open()
        for frame in reader:
            persons = detector.detect(frame.image, frame.info)
            print(_line(frame.info.seq, frame.info.capture_time, persons))
            sys.stdout.flush()
            if args.out:
                if writer is None:
                    h, w = frame.image.shape[:2]
                    writer = cv2.VideoWriter(str(args.out), cv2.VideoWriter_fourcc(*"mp4v"),
                                             reader.fps or 10.0, (w, h))
                    if not writer.isOpened():
                        raise InputError(f"{args.out}: cannot open a video writer")
                writer.write(draw_persons(frame.image, persons.boxes_px, persons.scores))
    finally:
        reader.close()
        if writer is not None:
            writer.release()
    return 0
