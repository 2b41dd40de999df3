"""Reading, validating, hashing and atomically saving zone files; the validated ``Cell``."""

from __future__ import annotations

import contextlib
import glob
import hashlib
import io
import json
import os
import re
import shutil
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import ValidationError

from monitor import geometry as geo
from monitor.errors import ConfigError
from monitor.zones.layout import Indent, guess_indent
from monitor.zones.prepare import PreparedCell, prepare_cell
from monitor.zones.schema import CameraSpec, CellSpec
from monitor.zones.validate import check_spec, pydantic_message, useful_errors

# --------------------------------------------------------------------------------------------
# The validated cell


@dataclass(frozen=True, eq=False)
class Cell:
    """A validated zone file.

    ``cameras`` maps camera id to its spec; ``zones`` keeps the file order (disabled zones
    included); ``config_hash`` names the active zone set (see ``config_hash``);
    ``camera_models`` holds the calibrated cameras; ``warnings`` are doubts that do not stop.
    """

    spec: CellSpec
    path: Path | None
    cameras: Mapping[str, CameraSpec]
    zones: tuple[Any, ...]
    config_hash: str
    camera_models: Mapping[str, geo.CameraModel]
    meshes: Mapping[str, tuple[np.ndarray, np.ndarray]]  # zone id or "tool" -> (vertices, faces)
    warnings: tuple[str, ...] = ()

    def zone(self, zone_id: str) -> Any:
        for z in self.zones:
            if z.id == zone_id:
                return z
        raise ConfigError(f"{self.label}: no zone '{zone_id}'")

    @property
    def has_protective_zone(self) -> bool:
        """An enabled protective zone exists. Without one a person anywhere is never a STOP:
        ``monitor run`` refuses such a file unless its configuration says so explicitly."""
        return any(z.enabled and z.kind == "protective" for z in self.zones)

    @property
    def label(self) -> str:
        return str(self.path) if self.path is not None else "<cell>"

    @cached_property
    def prepared(self) -> PreparedCell:
        """Geometry built once for the per-frame queries (cached on this object)."""
        return prepare_cell(self)


def draft_path(path: str | os.PathLike) -> Path:
    """The draft beside a zone file (``cell.yaml`` -> ``cell.draft.yaml``): an edit that
    weakens protection waits there for an operator's signed apply (docs/console.md)."""
    p = Path(path)
    return p.with_name(f"{p.stem}.draft{p.suffix}")


def load_cell(path: str | os.PathLike) -> Cell:
    """Read and validate a zone file; raises ConfigError (one line) on any fault."""
    return parse_cell(read_cell_data(path), path)


# libyaml's parser when PyYAML has it (about 10x faster on a large file); same constructor
_SafeBase: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _UniqueKeyLoader(_SafeBase):
    """SafeLoader that refuses a key given twice in one mapping (PyYAML keeps the last one
    silently, which could switch a zone's kind or enabled flag unnoticed)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if not isinstance(key, str | int | float | bool):
                raise yaml.constructor.ConstructorError(
                    None, None, f"a key must be a plain name, not {type(key).__name__}",
                    key_node.start_mark)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


# YAML 1.2 booleans only (true/false), as ruamel reads them too: PyYAML's YAML 1.1 also turns
# yes/no/on/off into booleans, so the two loaders would disagree on `enabled: off`.
_UniqueKeyLoader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_UniqueKeyLoader.add_implicit_resolver(
    "tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
    list("tTfF"))


def _read_yaml(path: str | os.PathLike, load: Any, errors: tuple[type[Exception], ...]) -> Any:
    """Read a zone file and parse it with ``load(text)``; one-line ConfigError on any fault,
    with the line and column of a YAML syntax error."""
    p = Path(path)
    try:
        if p.stat().st_size > MAX_ZONE_FILE_BYTES:
            raise ConfigError(f"{p}: zone file is larger than {MAX_ZONE_FILE_BYTES // 1_000_000} "
                              "MB: not a zone file")
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: zone file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read zone file: {exc}") from None
    depth = _nesting_depth(text)
    if depth > MAX_NESTING:
        raise ConfigError(f"{p}: brackets nested {depth} deep (at most "
                          f"{MAX_NESTING}): not a zone file")
    try:
        data = load(text)
    except errors as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or _first_line(exc)
        if "nesting depth" in str(problem):  # ruamel.yaml >= 0.19 has a depth limit of its own
            raise ConfigError(f"{p}{where}: nested more than {MAX_NESTING} levels deep: not a "
                              "zone file") from None
        raise ConfigError(f"{p}{where}: YAML syntax error: {problem}") from None
    except RecursionError:
        raise ConfigError(f"{p}: nested too deeply: not a zone file") from None
    except (TypeError, ValueError, AttributeError, OverflowError, KeyError) as exc:
        # a tag the loader cannot build (!!float abc, !!timestamp 99-99-99, ...)
        raise ConfigError(f"{p}: YAML value cannot be read: {_first_line(exc)}") from None
    if _data_depth(data) > MAX_NESTING:  # block (indented) nesting: no brackets to count
        raise ConfigError(f"{p}: nested more than {MAX_NESTING} levels deep: not a zone file")
    return data


MAX_ZONE_FILE_BYTES = 20_000_000
MAX_NESTING = 64  # a zone file nests about 6 deep (zones, zone, points, point)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0][:200] if text else type(exc).__name__)


def _data_depth(data: Any) -> int:
    """Nesting depth of loaded YAML data, without recursion (later stages recurse)."""
    best = 0
    stack = [(data, 1)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, dict | list | tuple):
            best = max(best, depth)
            if depth > MAX_NESTING:
                return depth
            items = node.values() if isinstance(node, dict) else node
            stack.extend((v, depth + 1) for v in items)
    return best


def _nesting_depth(text: str) -> int:
    """Deepest bracket nesting of flow collections, counted without parsing (the parsers
    recurse per level and would end in RecursionError). Brackets inside quotes count too:
    a zone file has no reason to quote 64 brackets in a row."""
    depth = best = 0
    for ch in text:
        if ch in "[{":
            depth += 1
            best = max(best, depth)
        elif ch in "]}":
            depth = max(depth - 1, 0)
    return best


def read_cell_data(path: str | os.PathLike) -> Any:
    """The YAML data of a zone file, unvalidated; ConfigError when unreadable or not YAML."""
    # a SafeLoader: no arbitrary objects; duplicate keys refused
    return _read_yaml(path, lambda text: yaml.load(text, Loader=_UniqueKeyLoader),
                      (yaml.YAMLError,))


def read_cell_document(path: str | os.PathLike) -> Any:
    """The zone file as an editable round-trip document (ruamel.yaml): dict- and list-like, and
    written back with its comments, key order and layout (``monitor zones`` edits use this)."""
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError as RtError

    # ruamel refuses duplicate keys too
    return _read_yaml(path, YAML(typ="rt").load, (RtError,))


def _flow_leaves(node: Any) -> Any:
    """New plain lists of numbers (points, matrices rows) in flow style: [x, y]."""
    from ruamel.yaml.comments import CommentedSeq

    if isinstance(node, dict):
        for key in list(node):
            node[key] = _flow_leaves(node[key])
        return node
    if isinstance(node, list):
        items = [_flow_leaves(v) for v in node]
        if isinstance(node, CommentedSeq):
            node[:] = items
            return node
        seq = CommentedSeq(items)
        if all(not isinstance(v, list | dict) for v in items):
            seq.fa.set_flow_style()
        return seq
    return node


def dump_cell_document(document: Any, indent: Indent | None = None) -> str:
    """The document as YAML text, indented as ``indent`` (default "key:\n  - item", as the
    zones/ files are; an edit passes the file's own, see monitor.zones.layout)."""
    from ruamel.yaml import YAML

    indent = indent or Indent()
    out = io.StringIO()
    yaml_rt = YAML(typ="rt")
    yaml_rt.width = 100
    yaml_rt.indent(mapping=indent.mapping, sequence=indent.sequence, offset=indent.offset)
    yaml_rt.dump(_flow_leaves(document), out)
    return out.getvalue()


def parse_cell(data: Any, path: str | os.PathLike | None = None) -> Cell:
    """Validate a zone file already parsed from YAML (a dict). Mesh paths are relative to the
    directory of ``path`` (the working directory without one)."""
    label = str(path) if path is not None else "<cell>"
    if not isinstance(data, dict):
        raise ConfigError(f"{label}: a zone file must be a YAML mapping with version, cameras, "
                          "zones")
    try:
        spec = CellSpec.model_validate(_as_tuples(data))
    except ValidationError as exc:
        raise ConfigError(f"{label}: {pydantic_message(exc, data, 0, useful_errors(exc, data))}"
                          ) from None
    base = Path(path).parent if path is not None else Path.cwd()
    errors, warnings, models, meshes = check_spec(spec, base)
    if errors:
        more = ""
        if len(errors) > 1:
            more = f" (and {len(errors) - 1} more; run 'monitor zones validate')"
        raise ConfigError(f"{label}: {errors[0]}{more}")
    return Cell(
        spec=spec,
        path=Path(path) if path is not None else None,
        cameras={c.id: c for c in spec.cameras},
        zones=tuple(spec.zones),
        config_hash=config_hash(spec, meshes_sha=_mesh_digests(spec, base)),
        camera_models=models,
        meshes=meshes,
        warnings=tuple(warnings),
    )


def cell_faults(data: Any, path: str | os.PathLike | None = None) -> tuple[list[str], list[str]]:
    """All errors and warnings of a zone file's data (for ``monitor zones validate``)."""
    if not isinstance(data, dict):
        return ["a zone file must be a YAML mapping with version, cameras, zones"], []
    try:
        spec = CellSpec.model_validate(_as_tuples(data))
    except ValidationError as exc:
        errs = useful_errors(exc, data)
        return [pydantic_message(exc, data, index=k, errors=errs) for k in range(len(errs))], []
    base = Path(path).parent if path is not None else Path.cwd()
    errors, warnings, _, _ = check_spec(spec, base)
    return errors, warnings


def _as_tuples(data: Any) -> Any:
    """YAML lists as tuples, so that the strict schema (no coercion: ``'no'`` is not a bool,
    ``'1.5'`` not a number) accepts them where it wants a tuple."""
    if isinstance(data, dict):
        return {k: _as_tuples(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return tuple(_as_tuples(v) for v in data)
    return data


def cell_to_data(cell_or_spec: Cell | CellSpec) -> dict:
    """Plain data (lists, dicts, numbers) of a cell, as it is written to YAML."""
    spec = cell_or_spec.spec if isinstance(cell_or_spec, Cell) else cell_or_spec
    data = spec.model_dump(mode="json", exclude_none=True)
    if not spec.sets:  # zone set keys only in files that use sets (docs/cases.md)
        data.pop("sets", None)
        data.pop("switch_over_s", None)
    return data


class ZoneDumper(yaml.SafeDumper):
    """Lists of numbers in flow style ([x, y]) so that polygons stay readable."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(not isinstance(v, list | dict) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


ZoneDumper.add_representer(list, _represent_list)


def dump_cell_yaml(cell_or_spec: Cell | CellSpec) -> str:
    header = ("# workcell-monitor zone file (format: zones/README.md). Written by "
              "'monitor zones new'.\n")
    body = yaml.dump(cell_to_data(cell_or_spec), Dumper=ZoneDumper, sort_keys=False,
                     allow_unicode=True, width=100)
    return header + body


def save_cell(cell: Cell, path: str | os.PathLike, document: Any = None) -> None:
    """Write the cell atomically: a temp file in the same directory is renamed over ``path``;
    an existing file is first copied to ``path.bak``. With ``document`` (from
    :func:`read_cell_document`, already validated as ``cell``) the file keeps its comments and
    its indentation.

    The file keeps its mode and owner; a read-only file is refused (not replaced), and so is a
    file whose owner this user cannot keep. Temp files are removed on every failure (a full
    disk, Ctrl-C); ones left by a killed run (``.<name>.*.tmp``, older than a minute) are
    removed at the next save. Any fault is a one-line ConfigError; the old file is untouched.
    """
    target = Path(path)
    text = dump_cell_document(document, _own_indent(target)) if document is not None \
        else dump_cell_yaml(cell)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        old = target.stat() if target.exists() else None
    except OSError as exc:
        raise ConfigError(f"{target}: cannot write zone file: {_first_line(exc)}") from None
    # no write bit at all is a deliberate "do not change" even for root (who may write anyway)
    if old is not None and (not os.access(target, os.W_OK) or not old.st_mode & 0o222):
        raise ConfigError(f"{target}: zone file is read-only: not replaced (make it writable "
                          "first)")
    _remove_stale_temp_files(target)
    tmp: Path | None = None
    bak_tmp = target.with_name(f".{target.name}.bak.tmp")
    try:
        fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
        tmp = Path(name)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        if old is not None:
            os.chmod(tmp, old.st_mode & 0o7777)
            if (old.st_uid, old.st_gid) != (os.getuid(), os.getgid()):
                try:
                    os.chown(tmp, old.st_uid, old.st_gid)
                except PermissionError:
                    raise ConfigError(f"{target}: zone file belongs to another user (uid "
                                      f"{old.st_uid}); replacing it would change its owner: "
                                      "edit it as that user") from None
        else:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        if old is not None:
            shutil.copy2(target, bak_tmp)
            os.replace(bak_tmp, target.with_name(target.name + ".bak"))
        os.replace(tmp, target)
        tmp = None
    except OSError as exc:
        raise ConfigError(f"{target}: cannot write zone file: {_first_line(exc)}") from None
    finally:  # also on Ctrl-C: no temp file stays behind
        for leftover in (tmp, bak_tmp):
            if leftover is not None:
                with contextlib.suppress(OSError):
                    leftover.unlink(missing_ok=True)


def _own_indent(target: Path) -> Indent | None:
    """The indentation of the file an edit replaces (None: a new file, the default)."""
    try:
        return guess_indent(target.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError):
        return None


STALE_TEMP_S = 60.0


def _remove_stale_temp_files(target: Path) -> None:
    """Temp files of an earlier run that was killed between writing and renaming. Only ours
    (``.<name>.<random>.tmp``) and only when older than a minute (not a parallel save)."""
    now = time.time()
    try:
        stale = list(target.parent.glob(f".{glob.escape(target.name)}.*.tmp"))
    except OSError:
        return
    for p in stale:
        with contextlib.suppress(OSError):
            if p.is_file() and not p.is_symlink() and now - p.stat().st_mtime > STALE_TEMP_S:
                p.unlink()


def promote_draft(path: str | os.PathLike, expected_hash: str) -> Cell:
    """Write the draft beside the zone file ``path`` (``draft_path``) into it, atomically and
    keeping ``path.bak``, when the draft's zone set is ``expected_hash`` (the signed one); the
    draft is then removed. ConfigError (one line, nothing written) otherwise."""
    draft = draft_path(path)
    data = read_cell_document(draft)
    cell = parse_cell(data, path)
    if cell.config_hash != expected_hash:
        raise ConfigError(f"{draft}: the draft changed after you signed: you signed "
                          f"{expected_hash[:12]}, it has {cell.config_hash[:12]} now")
    save_cell(cell, path, data)
    draft.unlink(missing_ok=True)
    return load_cell(path)


def write_cell_data(data: Any, path: str | os.PathLike) -> Cell:
    """Validate zone-file data and, only when valid, save it atomically to ``path`` (the
    previous file is kept as ``path.bak``). On a fault nothing is written."""
    from ruamel.yaml.comments import CommentedMap

    cell = parse_cell(data, path)
    save_cell(cell, path, data if isinstance(data, CommentedMap) else None)
    return cell


def _camera_data(camera: CameraSpec) -> dict:
    d = camera.model_dump(mode="json")
    if d.get("reference") is None:  # only when given: older files keep their hash
        d.pop("reference", None)
    return d


def _person_data(spec: CellSpec) -> dict:
    d = spec.person.model_dump(mode="json")
    for key in ("crouching_height_m", "visible_fraction"):
        if d.get(key) is None:  # only when given: older files keep their hash
            d.pop(key, None)
    return d


def config_hash(spec: CellSpec, meshes_sha: Mapping[str, str] | None = None) -> str:
    """Stable, order-independent name of the active configuration.

    sha256 over canonical JSON of the cameras (sorted by id), the ENABLED zones (sorted by id,
    display names left out, mesh files by content hash), the person, separation and tool
    settings. Reordering the file, renaming a zone's display name or adding a disabled zone
    keeps the hash; any change that can alter a decision changes it.
    """
    meshes_sha = meshes_sha or {}
    zones = []
    for z in spec.zones:
        if not z.enabled:
            continue
        d = z.model_dump(mode="json", exclude={"name", "enabled"})
        for key in ("unobserved_ok", "mute", "unmutable", "follow"):
            if d.get(key) is None:  # only when given: older files keep their hash
                d.pop(key, None)
        if z.shape == "mesh":
            d["file_sha256"] = meshes_sha.get(z.id, "")
        zones.append(d)
    tool = None
    if spec.tool is not None:
        tool = spec.tool.model_dump(mode="json")
        if spec.tool.shape == "mesh":
            tool["file_sha256"] = meshes_sha.get("tool", "")
    payload = {
        "version": spec.version,
        "cameras": sorted((_camera_data(c) for c in spec.cameras), key=lambda c: c["id"]),
        "zones": sorted(zones, key=lambda z: z["id"]),
        "person": _person_data(spec),
        "separation": spec.separation.model_dump(mode="json"),
        "tool": tool,
    }
    if spec.tracker_frame is not None:  # only when set: older files keep their hash
        payload["tracker_frame"] = spec.tracker_frame.model_dump(mode="json")
    if spec.floors:  # only when set: older files keep their hash
        payload["floors"] = sorted((f.model_dump(mode="json", exclude={"name"})
                                    for f in spec.floors), key=lambda f: f["id"])
    if spec.sets:  # only when set: older files keep their hash (monitor/cases/)
        payload["sets"] = {
            "sets": sorted((z.model_dump(mode="json", exclude={"name"}) for z in spec.sets),
                           key=lambda z: z["id"]),
            "default_set": spec.default_set,
            "transitions": sorted(spec.transitions) if spec.transitions is not None else None,
            "switch_over_s": spec.switch_over_s, "selector_ttl_s": spec.selector_ttl_s}
    if spec.robot_base is not None:  # only when set (the default base is fixed in code)
        payload["robot_base"] = spec.robot_base.model_dump(mode="json")
    blob = json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _mesh_digests(spec: CellSpec, base: Path) -> dict[str, str]:
    out = {}
    for z in spec.zones:
        if z.shape == "mesh":
            out[z.id] = hashlib.sha256((base / z.file).read_bytes()).hexdigest()
    if spec.tool is not None and spec.tool.shape == "mesh":
        out["tool"] = hashlib.sha256((base / spec.tool.file).read_bytes()).hexdigest()
    return out


