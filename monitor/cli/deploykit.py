"""The deploy kit and the docs shipped in the wheel, and the config ``monitor init`` writes.

In the wheel, deploy/ installs as ``monitor.deploy``, docs/ as ``monitor.docs``, zones/ (the zone
file guide and the demo cell) as ``monitor.zonedocs`` and models/ as ``monitor.models``
(pyproject.toml). In a source checkout the top-level folders are read directly, so a change to
them is what the tests see.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import monitor
from monitor.errors import ConfigError

PARTS = {"deploy": "monitor.deploy", "docs": "monitor.docs", "zones": "monitor.zonedocs",
         "models": "monitor.models"}


def kit_dir(part: str) -> Path:
    """The folder of a shipped part (deploy, docs, zones, models) on disk."""
    checkout = Path(monitor.__file__).resolve().parents[1]
    if (checkout / "pyproject.toml").is_file() and (checkout / part).is_dir():
        return checkout / part
    # installed: data folders inside the package (no __init__.py: read as files, not imported)
    path = Path(str(resources.files("monitor"))) / PARTS[part].removeprefix("monitor.")
    if not path.is_dir():
        raise ConfigError(f"the {part}/ files are missing from this installation; reinstall "
                          "workcell-monitor")
    return path


def kit_file(part: str, name: str) -> Path:
    path = kit_dir(part) / name
    if not path.is_file():
        raise ConfigError(f"{part}/{name} is missing from this installation; reinstall "
                          "workcell-monitor")
    return path


# --- the shipped docs -------------------------------------------------------------------------


def doc_files() -> dict[str, Path]:
    """Name -> file of every shipped document: docs/*.md by name, the zone file guide as
    ``zones``, the model card as ``model-card``."""
    out = {p.stem: p for p in sorted(kit_dir("docs").glob("*.md"))}
    for name, (part, file) in {"zones": ("zones", "README.md"),
                               "model-card": ("models", "README.md")}.items():
        path = kit_dir(part) / file
        if path.is_file():
            out[name] = path
    return out


def doc_title(path: Path) -> str:
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            return line.lstrip("#").strip()
    return ""


# --- monitor.toml for `monitor init` ----------------------------------------------------------


@dataclass(frozen=True)
class KitCamera:
    """A camera named on ``monitor init``'s command line."""

    id: str
    source: str
    width: int
    height: int
    live: bool  # a camera index or stream (not a file): the synthetic model is refused there


_CAMERA_BLOCK = re.compile(r"^\[camera\]\n(?:.+\n)*?(?=\n)", re.MULTILINE)
_ETC = '"/etc/workcell-monitor/'


def _toml_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def camera_tables(cameras: list[KitCamera]) -> str:
    out = []
    for cam in cameras:
        lines = ["[[camera]]",
                 f"id = {_toml_string(cam.id)}                       # as in the zone file",
                 f"source = {_toml_string(cam.source)}",
                 f'# reference = "references/{cam.id}.png"   # `monitor reference capture` '
                 "(cell empty)",
                 "realtime = true"]
        lines.append("loop = false" if cam.live else
                     "loop = true                       # a video file as a camera: play it "
                     "again at its end")
        out.append("\n".join(lines) + "\n")
    return "\n".join(out)


def render_config(template: str, cell: str, cameras: list[KitCamera],
                  listen: str | None = None) -> str:
    """deploy/monitor.toml with the named cameras as [[camera]] tables and every file path
    relative to the config's folder (monitor.toml resolves them there), so the folder can move
    to /etc/workcell-monitor as it is."""
    if not _CAMERA_BLOCK.search(template):
        raise ConfigError("deploy/monitor.toml has no [camera] table to replace")
    text = _CAMERA_BLOCK.sub(lambda _: camera_tables(cameras), template, count=1)
    text = text.replace(_ETC, '"')
    text = re.sub(r'^cell = "[^"]*"(.*)workcell/cell1/',
                  lambda m: f"cell = {_toml_string(cell)}{m.group(1)}workcell/{cell}/", text,
                  count=1, flags=re.MULTILINE)
    text = text.replace("deploy/zenoh/", "zenoh/")
    if listen:
        text = re.sub(r"^(zenoh_config_file = .*)$",
                      lambda m: f"{m.group(1)}\nlisten = [{_toml_string(listen)}]"
                      "         # overrides the Zenoh config's listen endpoints", text,
                      count=1, flags=re.MULTILINE)
    return text


_LAST_CAMERA = re.compile(r"^\[\[camera\]\]\n(?:.+\n)*", re.MULTILINE)


def add_camera_table(text: str, cam: KitCamera, where: str) -> str:
    """A config text with one more [[camera]] table, after the last one (or at the end)."""
    if re.search(r"^\[camera\]", text, re.MULTILINE):
        raise ConfigError(f"{where}: has a single [camera] table; write it as [[camera]] "
                          "first, then cameras can be added")
    table = camera_tables([cam])
    tables = list(_LAST_CAMERA.finditer(text))
    if not tables:
        return text.rstrip("\n") + "\n\n" + table
    end = tables[-1].end()
    return text[:end] + "\n" + table + text[end:]
