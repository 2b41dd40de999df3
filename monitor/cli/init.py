"""``monitor init DIR``: a deployment folder from the shipped kit; ``monitor docs``: the docs.

``init`` writes monitor.toml (the commented template with the named cameras, every path relative
to DIR), cell.yaml (the zone file with those cameras, no zones yet), the systemd unit, the Zenoh
configs, the monitor's signing key, operator keys and the operators file, commissioner keys and
the commissioners file, then prints what is left to do. It never overwrites a file unless
--force, and checks every file before writing any.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import sys
from pathlib import Path

from monitor import zones as zn
from monitor.cli.deploykit import KitCamera, doc_files, doc_title, kit_dir, kit_file, render_config
from monitor.cli.zone_cameras import media_size, new_zone_document, parse_size
from monitor.errors import ConfigError
from monitor.frames import source_kind
from monitor.wire.signing import new_key_pair

_ID = re.compile(r"^[A-Za-z0-9_.-]+$")
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"  # zenoh/peer.json5's listen endpoint


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "init", help="write a deployment folder: monitor.toml, zone file, systemd unit, Zenoh "
        "configs, keys, operators",
        description="Write a deployment folder from the kit shipped with the package: "
        "monitor.toml (every key explained, the named cameras, paths relative to DIR so the "
        "folder can be moved to /etc/workcell-monitor), cell.yaml (the zone file with those "
        "cameras), workcell-monitor.service, zenoh/*.json5, keys/monitor.key(.pub), operator "
        "keys and the operators file. Prints the next steps.")
    p.add_argument("dir", type=Path, help="folder to write (created when missing)")
    p.add_argument("--cell", default="cell1", help="cell name: Zenoh keys workcell/<cell>/...")
    p.add_argument("--camera", action="append", default=[], metavar="ID=SOURCE",
                   help="a camera and its source: index, rtsp:// URL or video file "
                   "(repeatable; e.g. --camera cam0=rtsp://10.0.0.21/stream1 --camera "
                   "cam1=/data/cam1.mp4; default: cam0=0, the first local camera)")
    p.add_argument("--size", help="resolution WxH of cameras that are not files (a video "
                   "file's own size is read from it); required for those")
    p.add_argument("--operator", action="append", default=[], metavar="NAME",
                   help="an operator who may reset a latched STOP: keys/NAME.key and a line in "
                   "the operators file (repeatable; default none: every reset is refused)")
    p.add_argument("--commissioner", action="append", default=[], metavar="NAME",
                   help="a commissioner who signs the commissioning report: keys/NAME.key and "
                   "a line in the commissioners file (repeatable; default none: no "
                   "commissioned record is accepted until one is listed)")
    p.add_argument("--listen", metavar="ENDPOINT",
                   help="Zenoh endpoint the monitor listens on (default: zenoh/peer.json5's, "
                   "tcp/127.0.0.1:7447)")
    p.add_argument("--force", action="store_true",
                   help="overwrite existing files (default: refuse, writing nothing)")
    p.set_defaults(func=cmd_init)

    p = subparsers.add_parser("docs", help="list the documentation shipped with the package, "
                              "or print one document")
    p.add_argument("name", nargs="?", help="document to print (default: list them)")
    p.set_defaults(func=cmd_docs)


def _cameras(args: argparse.Namespace) -> list[KitCamera]:
    specs = args.camera or ["cam0=0"]
    out: list[KitCamera] = []
    for spec in specs:
        cam_id, sep, source = spec.partition("=")
        cam_id, source = cam_id.strip(), source.strip()
        if not sep or not cam_id or not source:
            raise ConfigError(f"--camera {spec!r}: expected ID=SOURCE, e.g. cam0=rtsp://...")
        if not _ID.match(cam_id):
            raise ConfigError(f"--camera {spec!r}: a camera id has letters, digits, _ . - only")
        if any(c.id == cam_id for c in out):
            raise ConfigError(f"--camera {cam_id}: given twice")
        kind = source_kind(source)
        if kind in ("file", "image"):
            path = Path(source).expanduser().resolve()  # the folder moves; the video does not
            width, height = media_size(path, f"--camera {cam_id}")
            out.append(KitCamera(cam_id, str(path), width, height, live=False))
            continue
        if kind == "synthetic":
            raise ConfigError(f"--camera {cam_id}: the synthetic demo source needs no "
                              "deployment ('monitor run' alone plays it)")
        if not args.size:
            raise ConfigError(f"--camera {cam_id}: say the resolution of {source} with --size "
                              "WxH (a live source is not opened here)")
        width, height = parse_size(args.size)
        out.append(KitCamera(cam_id, source, width, height, live=True))
    return out


def _operators(names: list[str], flag: str = "--operator") -> list[str]:
    for name in names:
        if not _ID.match(name):
            raise ConfigError(f"{flag} {name!r}: letters, digits, _ . - only")
    if len(set(names)) != len(names):
        raise ConfigError(f"{flag}: a name is given twice")
    return names


def cmd_init(args: argparse.Namespace) -> int:
    out: Path = args.dir
    cameras = _cameras(args)
    operators = _operators(args.operator)
    commissioners = _operators(args.commissioner, "--commissioner")
    if set(operators) & set(commissioners):
        raise ConfigError(f"--commissioner {sorted(set(operators) & set(commissioners))[0]}: "
                          "also an --operator; one key, one role: give the commissioner "
                          "another name")
    if not _ID.match(args.cell):
        raise ConfigError(f"--cell {args.cell!r}: letters, digits, _ . - only")
    zenoh = sorted(kit_dir("deploy").joinpath("zenoh").glob("*.json5"))
    files = {Path("monitor.toml"), Path("cell.yaml"), Path("workcell-monitor.service"),
             Path("operators"), Path("commissioners"), Path("keys/monitor.key"),
             Path("keys/monitor.key.pub")}
    files |= {Path("zenoh") / p.name for p in zenoh}
    files |= {Path("keys") / f"{n}.key{s}" for n in operators + commissioners
              for s in ("", ".pub")}
    existing = sorted(str(out / f) for f in files if (out / f).exists())
    if existing and not args.force:
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise ConfigError(f"{existing[0]}: exists{more}; not overwriting (use --force)")

    template = kit_file("deploy", "monitor.toml").read_text(encoding="utf-8")
    config = render_config(template, args.cell, cameras, args.listen)
    out.mkdir(parents=True, exist_ok=True)
    # no zone yet: the next steps say so, not the zone file's warnings
    zn.write_cell_data(new_zone_document(args.cell, [(c.id, c.width, c.height)
                                                     for c in cameras]), out / "cell.yaml")
    (out / "monitor.toml").write_text(config, encoding="utf-8")
    shutil.copyfile(kit_file("deploy", "workcell-monitor.service"),
                    out / "workcell-monitor.service")
    (out / "zenoh").mkdir(exist_ok=True)
    for p in zenoh:
        shutil.copyfile(p, out / "zenoh" / p.name)
    keys = out / "keys"
    keys.mkdir(exist_ok=True)
    os.chmod(keys, 0o700)
    new_key_pair(keys / "monitor.key", force=True)
    lines = ["# operators who may reset a latched STOP: '<operator> ed25519:<base64>' per line",
             "# (`monitor keys new --operator NAME`); without a line every reset is refused"]
    for name in operators:
        _, _, text = new_key_pair(keys / f"{name}.key", force=True)
        lines.append(f"{name} {text}")
    (out / "operators").write_text("\n".join(lines) + "\n", encoding="utf-8")
    lines = ["# commissioners whose signed commissioned.json the monitor accepts: "
             "'<commissioner> ed25519:<base64>'",
             "# per line (`monitor keys new --commissioner NAME`); never an operator's key"]
    for name in commissioners:
        _, _, text = new_key_pair(keys / f"{name}.key", force=True)
        lines.append(f"{name} {text}")
    (out / "commissioners").write_text("\n".join(lines) + "\n", encoding="utf-8")
    _next_steps(out, args.cell, cameras, operators, args.listen, commissioners)
    return 0


def watch_endpoint(listen: str | None) -> str:
    """Where `monitor watch` on this host reaches a monitor listening on ``listen``."""
    endpoint = listen or DEFAULT_LISTEN
    return endpoint.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:")


def _next_steps(out: Path, cell: str, cameras: list[KitCamera], operators: list[str],
                listen: str | None = None, commissioners: list[str] | None = None) -> None:
    commissioners = commissioners or []
    written = ["monitor.toml", "cell.yaml", "workcell-monitor.service", "zenoh/*.json5",
               "keys/monitor.key(.pub)"] + [f"keys/{n}.key(.pub)"
                                            for n in operators + commissioners] + \
        ["operators", "commissioners"]
    print(f"wrote {out}/: {', '.join(written)} (cell {cell}, cameras "
          f"{', '.join(f'{c.id} {c.width}x{c.height}' for c in cameras)})")
    d = str(out)
    steps = [f"draw a protective zone for each camera: cell.yaml has none yet and 'monitor run' "
             f"refuses it until then:\n       monitor zones add {d}/cell.yaml robot-stop "
             f"'x,y x,y x,y ...' --kind protective --camera {cameras[0].id}\n"
             f"     check it over a frame: monitor zones preview {d}/cell.yaml --camera "
             f"{cameras[0].id} --frame frame.png --out preview.png; more cameras: monitor "
             f"zones camera add {d}/cell.yaml ID --source SOURCE --config {d}/monitor.toml"]
    live = [c.id for c in cameras if c.live]
    if live:
        steps.append(f"set [model] path in monitor.toml to your person model (ONNX): the "
                     f"synthetic test model is refused on live camera {', '.join(live)} "
                     "(docs: monitor docs models)")
    steps.append(f"with the cell empty, capture each camera's reference: monitor reference "
                 f"capture --config {d}/monitor.toml --camera {cameras[0].id} --out "
                 f"{d}/references/{cameras[0].id}.png; then uncomment its reference line")
    if operators:
        keys = ", ".join(f"keys/{n}.key" for n in operators)
        steps.append(f"give each operator their key ({keys}) and delete it here; the monitor "
                     "needs only the operators file")
    else:
        steps.append("add operators who may reset a STOP: monitor keys new --operator NAME, "
                     f"then its line into {d}/operators")
    signer = (f"{d}/keys/{commissioners[0]}.key (then move it off this host)" if commissioners
              else f"your key (monitor keys new --commissioner NAME, its line into "
              f"{d}/commissioners)")
    steps.append(f"after the walk test, sign the commissioning report: monitor commission "
                 f"report --config {d}/monitor.toml --walk WALK_DIR --key {signer} "
                 "(docs: monitor docs commissioning)")
    steps.append(f"controllers pin the monitor's public key {d}/keys/monitor.key.pub "
                 "(monitor docs consumer)")
    steps.append(f"try it: monitor run --config {d}/monitor.toml (monitor watch --cell {cell} "
                 f"--connect {watch_endpoint(listen)} --monitor-key {d}/keys/monitor.key.pub "
                 "beside it)")
    steps.append(f"install: copy {d}/ to /etc/workcell-monitor/ and workcell-monitor.service to "
                 "/etc/systemd/system/, then systemctl enable --now workcell-monitor; beyond "
                 "this host: monitor docs security")
    print("next:")
    for n, step in enumerate(steps, 1):
        print(f"  {n}. {step}")


def cmd_docs(args: argparse.Namespace) -> int:
    docs = doc_files()
    if args.name is None:
        width = max(len(n) for n in docs)
        for name, path in docs.items():
            print(f"{name.ljust(width)}  {doc_title(path)}")
        folder = next(iter(docs.values())).parent
        print(f"\nmonitor docs NAME prints one; the files are in {folder}")
        return 0
    name = args.name.removesuffix(".md")
    if name not in docs:
        raise ConfigError(f"no document {args.name!r} (documents: {', '.join(docs)})")
    sys.stdout.write(docs[name].read_text(encoding="utf-8"))
    return 0

