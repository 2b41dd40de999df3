"""``monitor commission``: prove the cell was commissioned right (docs/commissioning.md).

* ``walk``: the walk test on a video of the integrator walking the cell (replay's machinery):
  per zone the floor cells the person was seen in, blind spots, entries with their time to
  STOP, gaps in detection; a floor picture and a camera picture.
* ``report``: one self-contained printable HTML file with every figure of the configuration,
  signed with the commissioner's key, and ``commissioned.json`` beside the config (signed too:
  what ``monitor run`` accepts and ``monitor status`` compares).
* ``verify``: check a report's signature and name its signer.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

from monitor.commission.verdict import MIN_WALKED
from monitor.errors import InputError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "commission", help="the walk test and the commissioning report",
        description="Prove the cell was commissioned right: a walk test that shows where each "
        "protective zone sees a person and how fast each entry was stopped, and a report "
        "signed with the commissioner's key that the running monitor names in its status.")
    sub = parser.add_subparsers(dest="commission_command", metavar="ACTION", required=True)

    p = sub.add_parser(
        "walk", help="analyse a walk through the cell: coverage, entries, time to STOP, gaps",
        description="Records (--record) or takes (--video) a video of the integrator walking "
        "the cell (along each protective zone's boundary, through it, crouching at the "
        "corners), runs it through the monitor as `monitor replay` does (restart "
        "interlock auto: each entry its own STOP) and writes "
        "walk.json, floor.png, camera-<id>.png, events.jsonl, summary.json and "
        "annotated.mp4 into --out. Prints the verdict per zone and camera; exit 1 when one "
        "FAILs (nobody detected, a protective zone never entered, too little floor walked, a "
        "camera frozen or lost). A recording with more than 5 % of its frames repeated or "
        "missing is refused (exit 2) with the measured figures.")
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
    p.add_argument("--min-walked", type=float, default=MIN_WALKED, metavar="SHARE",
                   help="share of each protective zone's visible floor this walk must have "
                   "seen a person on, else that zone FAILs (the report merges several walks)")
    p.add_argument("--truth", type=Path, metavar="FILE", help="the video's ground truth (the "
                   "truth.json of a generated walk): entries then count from the first frame "
                   "a person truly stands in the zone, detected or not")
    p.set_defaults(func=cmd_walk)

    p = sub.add_parser(
        "report", help="the commissioning report (HTML), signed with the commissioner's key",
        description="Writes one self-contained, printable HTML report of the configuration "
        "(product version, model and zone file hashes, the model's measured envelope, every "
        "zone drawn, every changed setting, keys and operators, capacity, reaction time and "
        "S_p, the walk test, open warnings, sign-off fields), signed over every byte with "
        "the commissioner's Ed25519 key (--key; `monitor keys new --commissioner NAME`). "
        "With --config, commissioned.json beside it (signed too) records the configuration's "
        "fingerprint: `monitor run` accepts it when the key is in [service] "
        "commissioners_file, and `monitor status` says whether the running configuration "
        "still matches.")
    p.add_argument("--config", type=Path, help="monitor.toml (default: the embedded demo; "
                   "then no record is written)")
    p.add_argument("--walk", type=Path, metavar="DIR", action="append", default=[],
                   help="a `commission walk` output folder (repeatable: one walk per camera, "
                   "or several passes; they merge into the verdict)")
    p.add_argument("--min-walked", type=float, default=MIN_WALKED, metavar="SHARE",
                   help="share of each zone's visible floor the walks must have seen a person "
                   f"on, else that zone FAILs (default {MIN_WALKED:g})")
    p.add_argument("--status", type=Path, metavar="FILE", help="the running service's status "
                   "(`monitor status --json > status.json`): its capacity and reaction figures")
    p.add_argument("--key", type=Path, required=True, metavar="PRIVATE",
                   help="the commissioner's private key (`monitor keys new --commissioner "
                   "NAME`); with --config it must be listed in [service] commissioners_file")
    p.add_argument("--by", default="", help="who commissioned the cell (printed in the "
                   "sign-off; default: the key's name in the commissioners file)")
    p.add_argument("--date", default="", help="the date printed in the sign-off (default "
                   "blank: the report holds no clock, so it is reproducible)")
    p.add_argument("--out", type=Path, default=Path("commissioning-report.html"),
                   help="the report file")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("verify", help="check a report's (or commissioned.json's) signature and "
                       "name its signer",
                       description="Exit 0 when the report's (or the record's: then also the "
                       "report it names, beside it) signature covers its every byte "
                       "and (with --key or --config) was made by that key or by a listed "
                       "commissioner; 1 when the report was changed or signed by another key.")
    p.add_argument("report", type=Path, help="the report file, or commissioned.json")
    p.add_argument("--key", type=Path, metavar="PUB", help="the commissioner's public key "
                   "file: the report must be signed by it")
    p.add_argument("--config", type=Path, help="monitor.toml: the report must be signed by a "
                   "key of its [service] commissioners_file")
    p.set_defaults(func=cmd_verify)


def _model_path(config, model: Path | None) -> Path:
    from monitor.cli.run import ensure_model

    return Path(model) if model else ensure_model(config.model.path)


def cmd_walk(args: argparse.Namespace) -> int:
    from monitor.commission.cut_feet import FEET_HIDDEN_TEXT, walk_passes_hidden_feet
    from monitor.commission.details import zones as zone_details
    from monitor.commission.verdict import WalkLimits, camera_verdicts, zone_verdicts
    from monitor.commission.walk_video import read_walk, walk_video
    from monitor.config import load_config
    from monitor.detector import Detector
    from monitor.replay.video import ReplaySettings
    from monitor.service.setup import zones_file_of
    from monitor.zones import load_cell

    if not 0.05 <= args.cell_size <= 2.0:
        raise InputError(f"--cell-size {args.cell_size:g}: must be within [0.05, 2] m")
    if not 0.0 <= args.min_walked <= 1.0:
        raise InputError(f"--min-walked {args.min_walked:g}: a share within [0, 1]")
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
    recording = None
    if args.video is not None:
        video = args.video
    else:
        video, recording = _record(args, config)
    detector = Detector(_model_path(config, args.model), config.detector)
    recorded_from = config.cameras[0].id if args.record is not None else None
    settings = ReplaySettings(out_dir=args.out, camera_id=args.camera or recorded_from,
                              annotate=not args.no_video, progress=sys.stderr.isatty(),
                              policy=config.policy, health=config.health,
                              tick_s=config.service.tick_s,
                              allow_no_protective=config.zones.allow_no_protective,
                              reference=_walk_reference(config, cell,
                                                        args.camera or recorded_from))
    result, pictures = walk_video(video, detector, cell, settings, args.cell_size, args.truth,
                                  recording)
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
    feet_hidden = not walk_passes_hidden_feet(result.zones)
    if feet_hidden:
        print("the walk does not pass: a fixture the zone file does not declare hides feet in "
              "a protective zone (docs/occlusion.md)")
    print(f"outputs: {args.out}/ (walk.json, {', '.join(sorted(pictures.values()))})")
    data = read_walk(args.out)
    ours = [z for z in zone_details(cell) if z["camera"] in (None, data["camera"])]
    limits = WalkLimits(args.min_walked, config.policy.clear_time)
    verdicts = [v.to_dict() for v in zone_verdicts(ours, [data], limits)
                + camera_verdicts([data["camera"]], [data])]
    _print_verdict(verdicts)
    failed = feet_hidden or any(v["verdict"] == "FAIL" for v in verdicts)
    print(f"walk test {'FAIL' if failed else 'PASS'} (the report merges this walk with the "
          "others: `commission report --walk DIR --walk DIR2 ...`)")
    return 1 if failed else 0


def _walk_reference(config, cell, camera_id: str | None):
    """The walked camera's commissioning reference (None: none): its edges tell boxes cut
    off by a fixture the zone file does not declare."""
    from monitor.health.references import choose_reference, load_chosen_reference
    from monitor.zones.cameras import choose_camera

    camera = choose_camera(cell.cameras, camera_id, cell.label)
    configured = next((c.reference for c in config.cameras if c.id == camera), None)
    return load_chosen_reference(choose_reference(camera, configured, cell), cell)


def _record(args: argparse.Namespace, config) -> tuple[Path, dict]:
    """Record the walk from the config's camera (``--camera``, else its first) into
    OUT/walk.mp4; the path and the recording's figures. A recording with too many repeated or
    missing slots is refused (``recording.check``)."""
    from monitor.commission.recording import check, record_walk
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
    print(f"recorded {rec.frames} frames at {args.fps:g} fps into {path} ({rec.codec}): "
          f"{rec.frames - rec.repeated} distinct ({100 * rec.distinct_share:.0f} %), "
          f"{rec.repeated} repeated (camera slower), {rec.dropped} dropped (camera faster); "
          f"the camera gave {rec.camera_fps:.1f} fps")
    check(rec, args.fps)
    return path, rec.to_dict()


def cmd_report(args: argparse.Namespace) -> int:
    from monitor.commission.inputs import gather
    from monitor.commission.report import render, signed
    from monitor.commission.verdict import WalkLimits
    from monitor.config import load_config
    from monitor.service.commissioned import record_bytes, record_path, write_record
    from monitor.wire.signing import key_fingerprint, load_private_key

    config = load_config(args.config)
    signer = load_private_key(args.key)
    by = _commissioner(config, args, signer.public_text)
    model = _model_path(config, None)
    if not 0.0 <= args.min_walked <= 1.0:
        raise InputError(f"--min-walked {args.min_walked:g}: a share within [0, 1]")
    content = gather(args.config, model, args.walk, args.status, by, args.date,
                     signer.public_text, WalkLimits(args.min_walked))
    report = signed(render(content), signer)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_bytes(report)
    _print_verdict(content["verdicts"]["zones"] + content["verdicts"]["cameras"])
    print(f"open warnings: {len(content['warnings'])}")
    print(f"wrote {args.out}, signed by {by or 'an unnamed commissioner'} "
          f"(key {key_fingerprint(signer.public_text)})")
    if args.config is not None:
        record = record_path(args.config)
        write_record(record, record_bytes(report, args.out.name, by, content["fingerprint"],
                                          signer))
        print(f"recorded in {record} (signed; a running monitor takes it within seconds: "
              "monitor status: commissioned)")
    else:
        print("embedded demo: no commissioned.json written (pass --config)")
    return 0


def _print_verdict(verdicts: list[dict]) -> None:
    for v in verdicts:
        why = f": {'; '.join(v['reasons'])}" if v["reasons"] else ""
        print(f"{v['verdict']} {v['what']} {v['subject']}{why}")


def _commissioner(config, args: argparse.Namespace, public_text: str) -> str:
    """The signer's name: the commissioners file's name of the key (which must be listed
    when the report is for a config), else --by."""
    from monitor.wire.signing import load_operators, parse_public_key

    path = config.service.commissioners_file
    if args.config is None:
        return args.by
    if not path:
        print(f"warning: {args.config} has no [service] commissioners_file: the monitor "
              "accepts no commissioned record until one lists this key (`monitor keys new "
              "--commissioner NAME` printed the line)", file=sys.stderr)
        return args.by
    listed = load_operators(path, "commissioners file", "commissioner")
    key = parse_public_key(public_text)
    name = next((n for n, k in listed.items() if k == key), None)
    if name is None:
        raise InputError(f"{args.key}: this key is not listed in the commissioners file "
                         f"{path}: the monitor would refuse the record")
    if args.by and args.by != name:
        raise InputError(f"--by {args.by}: the key is {name}'s in {path}")
    return name


def cmd_verify(args: argparse.Namespace) -> int:
    from monitor.config import load_config
    from monitor.wire.evidence import NotSigned
    from monitor.wire.signing import key_fingerprint, load_operators, load_public_key

    try:
        data = args.report.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{args.report}: no such report") from None
    try:
        opened, named, report_ok = _open_evidence(args.report, data)
    except NotSigned as exc:
        print(f"CHANGED or not signed: {args.report}: {exc}")
        return 1
    fp = key_fingerprint(opened.key_text)
    if not opened.valid:
        print(f"CHANGED: {args.report}: the signature of key {fp} does not cover this content")
        return 1
    if report_ok is not None:  # a record: the report it names, beside it
        print(report_ok[1])
        if not report_ok[0]:
            return 1
    if args.key is not None:
        if load_public_key(args.key) != opened.key:
            print(f"OTHER KEY: {args.report} is intact but signed by key {fp}, not {args.key}")
            return 1
        print(f"ok: signed by {named} with {args.key} (key {fp}); every byte is as signed")
        return 0
    if args.config is not None:
        path = load_config(args.config).service.commissioners_file
        if not path:
            raise InputError(f"{args.config}: no [service] commissioners_file to check against")
        listed = load_operators(path, "commissioners file", "commissioner")
        name = next((n for n, k in listed.items() if k == opened.key), None)
        if name is None:
            print(f"NOT A COMMISSIONER: {args.report} is intact but signed by key {fp}, "
                  f"which is not in {path}")
            return 1
        print(f"ok: signed by commissioner {name} (key {fp}, {path}); every byte is as signed")
        return 0
    print(f"ok: every byte is as signed by key {fp}, named in it as {named}; pass "
          "--key PUB or --config to check that it is the commissioner's key")
    return 0


def _open_evidence(path: Path, data: bytes):
    """(opened, the signer it names, None or (ok, line) for a record's report): a report, or
    a commissioned.json record (then the report it names is checked by its SHA-256)."""
    from monitor.commission.report import signer_named, verify
    from monitor.service.commissioned import RECORD_LAYOUT
    from monitor.wire.evidence import open_signed

    if not data.startswith(b'{\n "record": '):
        opened = verify(data)
        return opened, signer_named(opened) or "nobody", None
    opened = open_signed(data, RECORD_LAYOUT)
    if not opened.valid:
        return opened, "nobody", None
    record = json.loads(data)["record"]
    report = path.parent / str(record.get("report"))
    if not report.is_file():
        return opened, record.get("by") or "nobody", (True, f"the report it names, {report}, "
                                                      "is not beside it (not checked)")
    same = hashlib.sha256(report.read_bytes()).hexdigest() == record.get("report_sha256")
    line = (f"the report {report.name} beside it is the one it names" if same else
            f"CHANGED: {report} is not the report this record names (another SHA-256)")
    return opened, record.get("by") or "nobody", (same, line)
