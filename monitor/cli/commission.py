"""``monitor commission``: prove the cell was commissioned right (docs/commissioning.md).

* ``walk``: the walk test on a video of the integrator walking the cell (replay's machinery):
  per zone the floor cells the person was seen in, blind spots, entries with their time to
  STOP, gaps in detection; a floor picture and a camera picture.
* ``report``: one self-contained printable HTML file with every figure of the configuration,
  its checksum, and ``commissioned.json`` beside the config (what ``monitor status`` compares).
* ``verify``: recompute a report's checksum.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from monitor.errors import InputError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "commission", help="the walk test and the commissioning report",
        description="Prove the cell was commissioned right: a walk test that shows where each "
        "protective zone sees a person and how fast each entry was stopped, and a report with "
        "a checksum that the running monitor names in its status.")
    sub = parser.add_subparsers(dest="commission_command", metavar="ACTION", required=True)

    p = sub.add_parser(
        "walk", help="analyse a walk through the cell: coverage, entries, time to STOP, gaps",
        description="Records (--record) or takes (--video) a video of the integrator walking "
        "the cell (along each protective zone's boundary, through it, crouching at the "
        "corners), runs it through the monitor as `monitor replay` does (restart "
        "interlock auto: each entry its own STOP) and writes "
        "walk.json, floor.png, camera-<id>.png, events.jsonl, summary.json and "
        "annotated.mp4 into --out.")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--video", type=Path, help="a recorded walk (one of --video, --record "
                        "is required)")
    source.add_argument("--record", type=float, metavar="SECONDS",
                        help="record the walk from the config's camera (--camera) for this "
                        "long into OUT/walk.mp4 first, then analyse it")
    p.add_argument("--fps", type=float, default=10.0, help="frame rate of the --record video")
    p.add_argument("--config", type=Path, help="monitor.toml: its zones, model, policy and "
                   "detector settings (default: the embedded demo)")
    p.add_argument("--zones", type=Path, help="zone file (default: the config's)")
    p.add_argument("--camera", help="the zone file's camera the video comes from (default: "
                   "its only camera)")
    p.add_argument("--model", type=Path, help="ONNX model (default: the config's)")
    p.add_argument("--out", type=Path, default=Path("commission-walk"), help="output folder")
    p.add_argument("--cell-size", type=float, default=0.25, metavar="M",
                   help="floor cell size in metres")
    p.add_argument("--no-video", action="store_true", help="no annotated.mp4 (faster)")
    p.add_argument("--truth", type=Path, metavar="FILE", help="the video's ground truth (the "
                   "truth.json of a generated walk): entries then count from the first frame "
                   "a person truly stands in the zone, detected or not")
    p.set_defaults(func=cmd_walk)

    p = sub.add_parser(
        "report", help="the commissioning report (HTML) and its checksum",
        description="Writes one self-contained, printable HTML report of the configuration "
        "(product version, model and zone file hashes, the model's measured envelope, every "
        "zone drawn, every changed setting, keys and operators, capacity, reaction time and "
        "S_p, the walk test, open warnings, sign-off fields) and prints its checksum. With "
        "--config, commissioned.json beside it records the checksum: `monitor status` then "
        "says whether the running configuration still matches.")
    p.add_argument("--config", type=Path, help="monitor.toml (default: the embedded demo; "
                   "then no record is written)")
    p.add_argument("--walk", type=Path, metavar="DIR", help="a `commission walk` output folder")
    p.add_argument("--status", type=Path, metavar="FILE", help="the running service's status "
                   "(`monitor status --json > status.json`): its capacity and reaction figures")
    p.add_argument("--by", default="", help="who commissioned the cell (printed in the "
                   "sign-off; default blank)")
    p.add_argument("--date", default="", help="the date printed in the sign-off (default "
                   "blank: the report holds no clock, so it is reproducible)")
    p.add_argument("--out", type=Path, default=Path("commissioning-report.html"),
                   help="the report file")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("verify", help="check a report's printed checksum against its content",
                       description="Exit 0 when the report's checksum matches its content, "
                       "1 when it was changed.")
    p.add_argument("report", type=Path, help="the report file")
    p.set_defaults(func=cmd_verify)


def _model_path(config, model: Path | None) -> Path:
    from monitor.cli.run import ensure_model

    return Path(model) if model else ensure_model(config.model.path)


def cmd_walk(args: argparse.Namespace) -> int:
    from monitor.commission.cut_feet import FEET_HIDDEN_TEXT, walk_passes_hidden_feet
    from monitor.commission.walk_video import walk_video
    from monitor.config import load_config
    from monitor.detector import Detector
    from monitor.replay.video import ReplaySettings
    from monitor.service.setup import zones_file_of
    from monitor.zones import load_cell

    if not 0.05 <= args.cell_size <= 2.0:
        raise InputError(f"--cell-size {args.cell_size:g}: must be within [0.05, 2] m")
    if args.video is not None and not args.video.is_file():
        raise InputError(f"{args.video}: no such video")
    if args.record is not None and not 1.0 <= args.record <= 3600.0:
        raise InputError(f"--record {args.record:g}: must be within [1, 3600] s")
    if not 1.0 <= args.fps <= 60.0:
        raise InputError(f"--fps {args.fps:g}: must be within [1, 60]")
    if args.truth is not None and args.video is None:
        raise InputError("--truth: only with --video (a recording has no ground truth)")
    if args.truth is not None and not args.truth.is_file():
        raise InputError(f"{args.truth}: no such ground-truth file")
    config = load_config(args.config)
    zones = args.zones or zones_file_of(config)
    if zones is None:
        raise InputError("no zone file: pass --zones or a --config with [zones] file")
    cell = load_cell(zones)
    video = args.video if args.video is not None else _record(args, config)
    detector = Detector(_model_path(config, args.model), config.detector)
    recorded_from = config.cameras[0].id if args.record is not None else None
    settings = ReplaySettings(out_dir=args.out, camera_id=args.camera or recorded_from,
                              annotate=not args.no_video, progress=sys.stderr.isatty(),
                              policy=config.policy, health=config.health,
                              tick_s=config.service.tick_s,
                              allow_no_protective=config.zones.allow_no_protective,
                              reference=_walk_reference(config, cell,
                                                        args.camera or recorded_from))
    result, pictures = walk_video(video, detector, cell, settings, args.cell_size, args.truth)
    for z in result.zones:
        cover = (f"{z.seen_cells}/{z.cells} floor cells seen, {len(z.blind_spots)} blind"
                 if z.cells else "image zone (no floor)")
        times = ", ".join("no STOP" if e.time_to_stop_s is None else f"{e.time_to_stop_s:.2f} s"
                          for e in z.entries) or "none"
        corners = (f"; corners seen {sum(c.seen for c in z.corners)}/{len(z.corners)}"
                   if z.corners and z.kind == "protective" else "")
        print(f"{z.kind} {z.zone_id}: {cover}; entries {len(z.entries)} (to "
              f"{'STOP' if z.kind == 'protective' else 'SLOW'}: {times}); gaps {len(z.gaps)}"
              f"{corners}")
        if z.feet_hidden:
            print(f"{z.kind} {z.zone_id}: {len(z.feet_hidden)} floor cells where the walker's "
                  f"feet were hidden ({FEET_HIDDEN_TEXT})")
    if not walk_passes_hidden_feet(result.zones):
        print("the walk does not pass: a fixture the zone file does not declare hides feet in "
              "a protective zone (docs/occlusion.md)")
    print(f"outputs: {args.out}/ (walk.json, {', '.join(sorted(pictures.values()))})")
    return 0


def _walk_reference(config, cell, camera_id: str | None):
    """The walked camera's commissioning reference (None: none): its edges tell boxes cut
    off by a fixture the zone file does not declare."""
    from monitor.health.references import choose_reference, load_chosen_reference
    from monitor.zones.cameras import choose_camera

    camera = choose_camera(cell.cameras, camera_id, cell.label)
    configured = next((c.reference for c in config.cameras if c.id == camera), None)
    return load_chosen_reference(choose_reference(camera, configured, cell), cell)


def _record(args: argparse.Namespace, config) -> Path:
    """Record the walk from the config's camera (``--camera``, else its first) into
    OUT/walk.mp4; the path."""
    from monitor.commission.recording import record_walk
    from monitor.frames import SourceOptions, open_source
    from monitor.signals import StopSignals

    cams = {c.id: c for c in config.cameras}
    cam = cams.get(args.camera) if args.camera else config.cameras[0]
    if cam is None:
        raise InputError(f"--camera {args.camera}: not in the config (has {', '.join(cams)})")
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "walk.mp4"
    with StopSignals(name="monitor commission walk") as stop:
        source = open_source(cam.source, cam.id, realtime=cam.realtime,
                             options=SourceOptions(), stop=stop)
        print(f"recording {args.record:g} s of {cam.id} ({cam.source}): walk the cell now",
              file=sys.stderr, flush=True)
        try:
            rec = record_walk(source, path, args.record, args.fps, stop)
        finally:
            source.close()
    print(f"recorded {rec.frames} frames at {args.fps:g} fps into {path} ({rec.codec}); "
          f"{rec.repeated} repeated (camera slower), {rec.dropped} dropped (camera faster)")
    return path


def cmd_report(args: argparse.Namespace) -> int:
    from monitor.commission.inputs import gather
    from monitor.commission.report import printed_checksum, render
    from monitor.config import load_config
    from monitor.service.commissioned import record_path, write_record

    config = load_config(args.config)
    model = _model_path(config, None)
    content = gather(args.config, model, args.walk, args.status, args.by, args.date)
    html = render(content)
    checksum = printed_checksum(html)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(html)
    print(f"wrote {args.out}")
    print(f"checksum {checksum}")
    if args.config is not None:
        record = record_path(args.config)
        write_record(record, checksum, content["fingerprint"], args.out.name, args.by)
        print(f"recorded in {record} (monitor status: commissioned)")
    else:
        print("embedded demo: no commissioned.json written (pass --config)")
    return 0


def cmd_verify(args: argparse.Namespace) -> int:
    from monitor.commission.report import verify

    try:
        html = args.report.read_text()
    except FileNotFoundError:
        raise InputError(f"{args.report}: no such report") from None
    except UnicodeDecodeError:
        raise InputError(f"{args.report}: not a report (not text)") from None
    ok, printed = verify(html)
    if printed is None:
        raise InputError(f"{args.report}: no checksum line: not a commissioning report")
    print(f"{'ok' if ok else 'CHANGED'}: printed checksum {printed}")
    return 0 if ok else 1
