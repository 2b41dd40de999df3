"""`monitor replay`, `monitor demo` and `monitor run`: the product's main commands.

Each installs its SIGINT/SIGTERM handlers first (``monitor.signals.StopSignals``), before the
model runtime and the Zenoh session load: a signal in any phase ends the command within 2 s,
a second one at once.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from monitor.errors import InputError

RUN_DESCRIPTION = """\
Run the monitor service: cameras in, RUN / SLOW / STOP commands, alerts and status out over
Zenoh. Without --config it plays the embedded demo: the synthetic demo scene (camera
"synthetic:demo") with the demo zone file, the synthetic model, and a Zenoh peer listening on
tcp/127.0.0.1:7447 (key prefix workcell/cell1/). SIGINT or SIGTERM publishes a final STOP and
exits 0; a second signal exits at once."""


def reset_times(text: str) -> tuple[float, ...]:
    """``--reset-at 18`` or ``--reset-at 18,30``: video seconds, finite and not negative."""
    out = []
    for part in text.split(","):
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{part!r} is not a time in seconds") from None
        if not math.isfinite(value) or value < 0:
            raise argparse.ArgumentTypeError(f"{part} s is not a video time (0 or more seconds)")
        out.append(value)
    return tuple(out)


def accept_time(text: str) -> tuple[float, str]:
    """``--accept-at 9:robot-protective``: a video time and the zone of the object accepted."""
    when, sep, zone = text.partition(":")
    if not sep or not zone.strip():
        raise argparse.ArgumentTypeError(f"{text!r}: give SECONDS:ZONE, e.g. 9:robot-protective")
    (t,) = reset_times(when)
    return t, zone.strip()


def register(subparsers: argparse._SubParsersAction) -> None:
    rp = subparsers.add_parser(
        "replay", help="run the monitor over a recorded video",
        description="Run the live pipeline over a recorded video on its own clock and write "
        "events.jsonl, summary.json, annotated.mp4 and snapshots/ into --out. Ctrl-C stops "
        "early: the files are finished, summary.json says where it stopped, exit 130.")
    rp.add_argument("video", type=Path, help="the video file (MP4, AVI, MKV, ...)")
    rp.add_argument("--zones", type=Path,
                    help="zone file (YAML); default: none (persons cannot cause SLOW/STOP)")
    rp.add_argument("--model", type=Path,
                    help="ONNX model (default: the synthetic model, built on first use)")
    rp.add_argument("--config", type=Path,
                    help="monitor.toml for policy/health/detector/bus settings "
                    "(default: built-in defaults)")
    rp.add_argument("--camera", help="camera id in the zone file (default: its only camera; "
                    "required when it has several)")
    rp.add_argument("--out", type=Path, default=Path("replay-out"),
                    help="output directory (default: replay-out)")
    rp.add_argument("--realtime", action="store_true",
                    help="play at the video's frame rate (default: as fast as possible)")
    rp.add_argument("--publish", action="store_true",
                    help="also publish commands and alerts over Zenoh (bus settings of --config; "
                    "default: off)")
    rp.add_argument("--reset-at", type=reset_times, action="append", default=[],
                    metavar="SECONDS",
                    help="video time at which an operator reset is sent; repeat the option or "
                    "give a comma list (--reset-at 8 --reset-at 18, or --reset-at 8,18); "
                    "default: no reset")
    rp.add_argument("--accept-at", type=accept_time, action="append", default=[],
                    metavar="SECONDS:ZONE",
                    help="video time at which an operator accepts the objects standing in ZONE "
                    "since commissioning (as `monitor objects accept`; needs --reference); "
                    "repeat for several; default: none")
    rp.add_argument("--reference", type=Path,
                    help="commissioning image of the camera (default: none, no moved/defocus "
                    "checks)")
    rp.add_argument("--no-video", action="store_true",
                    help="skip annotated.mp4 (default: write it)")
    rp.add_argument("--allow-no-protective", action="store_true",
                    help="accept a zone file without an enabled protective zone (default: "
                    "refuse it; also [zones] allow_no_protective in --config)")
    rp.add_argument("--incidents", type=Path, metavar="DIR",
                    help="record incidents (clips, index) into DIR with the [recorder] settings "
                    "of --config (default: no recording)")
    rp.set_defaults(func=cmd_replay)

    demo = subparsers.add_parser(
        "demo", help="build the model, generate the demo scene, replay it (the embedded "
        "default: no camera, no router, no downloads)",
        description="Build the synthetic model, render the demo scene (a person walks through "
        "the warning zone into the protective zone and out), and replay it with a reset at "
        "18 s.")
    demo.add_argument("--out", type=Path, default=Path("monitor-demo"),
                      help="output directory (default: monitor-demo)")
    demo.add_argument("--zones", type=Path,
                      help="zone file to replay the scene with (default: the demo zone file "
                      "shipped with the package)")
    demo.set_defaults(func=cmd_demo)

    run = subparsers.add_parser(
        "run", help="run the monitor service (default: the demo scene, Zenoh peer listening on "
        "tcp/127.0.0.1:7447)", description=RUN_DESCRIPTION)
    run.add_argument("--config", type=Path,
                     help="monitor.toml ('monitor init DIR' writes one, every key explained); "
                     "default: the embedded demo")
    run.add_argument("--log-json", action="store_true",
                     help="one JSON object per log line (default: text, or [service] log_json)")
    run.add_argument("--duration", type=float,
                     help="stop after this many seconds (default: run until SIGINT/SIGTERM)")
    run.add_argument("--capacity-check", choices=("refuse", "warn", "off"),
                     help="override [service] capacity_check for this run (e.g. warn while "
                     "commissioning on a busy host; default: the config's, refuse)")
    run.set_defaults(func=cmd_run)


def _load_reference(path: Path | None):
    if path is None:
        return None
    from monitor.health import load_reference

    return load_reference(path)


def do_replay(video: Path, zones: Path | None, model: Path | None, config_path: Path | None,
              out: Path, camera: str | None = None, realtime: bool = False,
              publish: bool = False, reset_at: tuple[float, ...] = (),
              reference: Path | None = None, annotate: bool = True, stop=None,
              allow_no_protective: bool = False, incidents: Path | None = None,
              accept_at: tuple[tuple[float, str], ...] = ()):
    from monitor.config import load_config
    from monitor.detector import Detector
    from monitor.driver import require_protective_zone
    from monitor.incidents.settings import config_hash
    from monitor.replay.video import ReplaySettings, replay
    from monitor.zones import load_cell
    from monitor.zones.cameras import choose_camera

    if not video.exists():
        raise InputError(f"{video}: no such file")
    config = load_config(config_path)
    allow = allow_no_protective or config.zones.allow_no_protective
    cell = load_cell(zones) if zones else None
    if cell is not None:  # before the model loads: a missing --camera is said at once
        choose_camera(cell.cameras, camera, cell.label)
    if publish and cell is None:  # commands to a robot: the same rule as `monitor run`
        require_protective_zone(None, allow, "")
    detector = Detector(model if model else ensure_model(config.model.path),
                        config.detector)
    settings = ReplaySettings(out_dir=out, camera_id=camera, reset_at=tuple(reset_at),
                              accept_at=tuple(accept_at),
                              realtime=realtime, annotate=annotate, policy=config.policy,
                              health=config.health, reference=_load_reference(reference),
                              tick_s=config.service.tick_s, allow_no_protective=allow,
                              self_test_period_s=getattr(config.detector, "self_test_period_s",
                                                         None),
                              incidents_dir=incidents, recorder=config.recorder,
                              config_hash=config_hash(config_path))
    if not publish:
        return replay(video, detector, cell, settings, stop=stop)
    from monitor.bus.session import SafetyBus
    from monitor.pipeline.pocket_views import screen_body
    from monitor.service.setup import bus_config_for

    with SafetyBus(bus_config_for(config, cell)) as bus:
        def send(result) -> None:
            bus.publish_command(result.command)
            for alert in result.alerts:
                bus.publish_alert(alert)
            if result.frame is not None:
                bus.publish_detections(result.persons, result.zone_report,
                                       **screen_body(result.areas, result.unseen,
                                                     result.pockets,
                                                     result.frame.camera_id))
        return replay(video, detector, cell, settings, publish=send, stop=stop)


def _signals():
    from monitor.signals import StopSignals

    return StopSignals().install()


def _report(summary, out: Path, annotate: bool) -> None:
    print(summary.table())
    files = ["events.jsonl", "summary.json"] + (["annotated.mp4"] if annotate else [])
    print(f"outputs: {out}/ ({', '.join(files)})")


def cmd_replay(args: argparse.Namespace) -> int:
    signals = _signals()
    try:
        reset_at = tuple(t for group in args.reset_at for t in group)
        summary = do_replay(args.video, args.zones, args.model, args.config, args.out,
                            args.camera, args.realtime, args.publish, reset_at, args.reference,
                            not args.no_video, stop=signals.stop,
                            allow_no_protective=args.allow_no_protective,
                            incidents=args.incidents, accept_at=tuple(args.accept_at))
        _report(summary, args.out, not args.no_video)
        if summary.interrupted:
            print(f"monitor: interrupted {summary.interrupted}: partial outputs finished in "
                  f"{args.out}/", file=sys.stderr)
            signals.exit_now(signals.exit_code)
        if summary.truncated:  # the readable part was processed; still a bad input: say so
            raise InputError(summary.truncated)
        return 0
    finally:
        signals.restore()


# The demo: the person leaves the protective zone at ~11 s and the view at ~17 s; the operator
# resets at 18 s, and RUN returns after clear_time.
DEMO_RESET_AT = (18.0,)


def render_progress(frames, total: int, label: str = "rendering scene"):
    """Yield ``frames``, with a tqdm bar on a terminal (stderr); silent otherwise."""
    from monitor.progress import progress

    yield from progress(frames, total, label, unit="frame")


def ensure_model(path: Path | None = None) -> Path:
    """The synthetic model, built when absent; the build shows progress on a terminal."""
    from monitor.models import synthetic
    from monitor.progress import Steps

    target = Path(path) if path else synthetic.default_model_path()
    older = path is None and synthetic.is_older_build(target)
    if target.is_file() and not older:
        return target
    steps = Steps(["fp32 model"], "model build")
    steps.start("building the synthetic model" + (" (replacing an earlier version's build)"
                                                  if older else ""))
    try:
        return synthetic.ensure_model(path)
    finally:
        steps.done()


def cmd_demo(args: argparse.Namespace) -> int:
    signals = _signals()
    try:
        code = _demo(args, signals)
        if signals.received is not None:
            signals.exit_now(code)
        return code
    finally:
        signals.restore()


def _demo(args: argparse.Namespace, signals) -> int:
    from monitor.config import demo_cell_path
    from monitor.scene import DemoScene, write_video

    out: Path = args.out
    zones = args.zones or demo_cell_path()
    if not zones.exists():
        raise InputError(f"{zones}: no such zone file")
    model = ensure_model()
    print(f"model:  {model}")
    scene = DemoScene()
    video = out / "demo-scene.mp4"

    def frames():
        for item in scene.frames():
            if signals.stop.is_set():
                return
            yield item
    truths = write_video(video, render_progress(frames(), scene.n_frames), scene.fps)
    if signals.stop.is_set():
        print(f"monitor: interrupted while rendering the scene ({len(truths)} of "
              f"{scene.n_frames} frames in {video})", file=sys.stderr)
        return signals.exit_code
    (out / "demo-truth.jsonl").write_text("".join(
        json.dumps({"frame": t.index, "time_s": round(t.time_s, 4),
                    "persons": [list(p.box_px) for p in t.persons]}) + "\n" for t in truths))
    print(f"scene:  {video} ({len(truths)} frames, {scene.fps:g} fps; ground truth in "
          f"demo-truth.jsonl)")
    summary = do_replay(video, zones, model, None, out, reset_at=DEMO_RESET_AT,
                        stop=signals.stop)
    print(summary.table())
    if summary.interrupted:
        print(f"monitor: interrupted {summary.interrupted}: partial outputs finished in {out}/",
              file=sys.stderr)
        return signals.exit_code
    print(f"\noutputs in {out}/: annotated.mp4 (what the monitor saw), events.jsonl (every "
          f"command change and alert), summary.json")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    signals = _signals()  # first: a signal while the model or Zenoh loads is honoured too
    try:
        from monitor.service.run import run_service

        code = run_service(args.config, log_json=args.log_json, duration=args.duration,
                           signals=signals, capacity_check=args.capacity_check)
        if signals.received is not None:  # stopped by a signal: everything is closed
            signals.exit_now(code)
        return code
    finally:
        signals.restore()
