"""`monitor replay`, `monitor demo` and `monitor run`: the product's main commands."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from monitor.errors import InputError


def register(subparsers: argparse._SubParsersAction) -> None:
    rp = subparsers.add_parser("replay", help="run the monitor over a recorded video")
    rp.add_argument("video", type=Path)
    rp.add_argument("--zones", type=Path, help="zone file (YAML); without it no zone applies")
    rp.add_argument("--model", type=Path, help="ONNX model (default: the synthetic model)")
    rp.add_argument("--config", type=Path, help="monitor.toml for policy/health/detector settings")
    rp.add_argument("--camera", help="camera id in the zone file (default: its only camera)")
    rp.add_argument("--out", type=Path, default=Path("replay-out"), help="output directory")
    rp.add_argument("--realtime", action="store_true", help="play at the video's frame rate")
    rp.add_argument("--publish", action="store_true",
                    help="also publish commands and alerts over Zenoh (bus settings of --config)")
    rp.add_argument("--reset-at", type=float, nargs="*", default=[], metavar="SECONDS",
                    help="video times at which an operator reset is sent")
    rp.add_argument("--reference", type=Path, help="commissioning image of the camera")
    rp.add_argument("--no-video", action="store_true", help="skip annotated.mp4")
    rp.set_defaults(func=cmd_replay)

    demo = subparsers.add_parser("demo", help="build the model, generate the demo scene, replay "
                                 "it (the embedded default: no camera, no router, no downloads)")
    demo.add_argument("--out", type=Path, default=Path("monitor-demo"), help="output directory")
    demo.set_defaults(func=cmd_demo)

    run = subparsers.add_parser("run", help="run the monitor service (default: the demo scene, "
                                "Zenoh peer on 127.0.0.1)")
    run.add_argument("--config", type=Path, help="monitor.toml (see deploy/monitor.toml)")
    run.add_argument("--log-json", action="store_true", help="one JSON object per log line")
    run.add_argument("--duration", type=float, help="stop after this many seconds")
    run.set_defaults(func=cmd_run)


def _load_reference(path: Path | None):
    if path is None:
        return None
    from monitor.health import load_reference

    return load_reference(path)


def do_replay(video: Path, zones: Path | None, model: Path | None, config_path: Path | None,
              out: Path, camera: str | None = None, realtime: bool = False,
              publish: bool = False, reset_at: tuple[float, ...] = (),
              reference: Path | None = None, annotate: bool = True):
    from monitor.config import load_config
    from monitor.detector import Detector
    from monitor.models import synthetic
    from monitor.replay import ReplaySettings, replay
    from monitor.zones import load_cell

    if not video.exists():
        raise InputError(f"{video}: no such file")
    config = load_config(config_path)
    cell = load_cell(zones) if zones else None
    detector = Detector(model if model else synthetic.ensure_model(config.model.path),
                        config.detector)
    settings = ReplaySettings(out_dir=out, camera_id=camera, reset_at=tuple(reset_at),
                              realtime=realtime, annotate=annotate, policy=config.policy,
                              health=config.health, reference=_load_reference(reference))
    if not publish:
        return replay(video, detector, cell, settings)
    from monitor.bus import SafetyBus
    from monitor.service import bus_config_for

    with SafetyBus(bus_config_for(config, cell)) as bus:
        def send(result) -> None:
            bus.publish_command(result.command)
            for alert in result.alerts:
                bus.publish_alert(alert)
            bus.publish_detections(result.persons, result.zone_report)
        return replay(video, detector, cell, settings, publish=send)


def cmd_replay(args: argparse.Namespace) -> int:
    summary = do_replay(args.video, args.zones, args.model, args.config, args.out, args.camera,
                        args.realtime, args.publish, tuple(args.reset_at or ()), args.reference,
                        not args.no_video)
    print(summary.table())
    print(f"outputs: {args.out}/ (events.jsonl, summary.json"
          + (", annotated.mp4)" if not args.no_video else ")"))
    if summary.truncated:  # the readable part was processed; still a bad input: say so, exit 2
        raise InputError(summary.truncated)
    return 0


# The demo: the person leaves the protective zone at ~11 s and the view at ~17 s; the operator
# resets at 18 s, and RUN returns after clear_time.
DEMO_RESET_AT = (18.0,)


def cmd_demo(args: argparse.Namespace) -> int:
    from monitor.config import demo_cell_path
    from monitor.models import synthetic
    from monitor.scene import DemoScene, write_video

    out: Path = args.out
    model = synthetic.ensure_model()
    print(f"model:  {model}")
    scene = DemoScene()
    video = out / "demo-scene.mp4"
    truths = write_video(video, scene.frames(), scene.fps)
    (out / "demo-truth.jsonl").write_text("".join(
        json.dumps({"frame": t.index, "time_s": round(t.time_s, 4),
                    "persons": [list(p.box_px) for p in t.persons]}) + "\n" for t in truths))
    print(f"scene:  {video} ({len(truths)} frames, {scene.fps:g} fps; ground truth in "
          f"demo-truth.jsonl)")
    summary = do_replay(video, demo_cell_path(), model, None, out, reset_at=DEMO_RESET_AT)
    print(summary.table())
    print(f"\noutputs in {out}/: annotated.mp4 (what the monitor saw), events.jsonl (every "
          f"command change and alert), summary.json")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from monitor.service import run_service

    return run_service(args.config, log_json=args.log_json, duration=args.duration)
