"""Reading, validating, hashing and atomically saving zone files; the validated ``Cell``."""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml
from pydantic import ValidationError

from monitor import geometry as geo
from monitor.errors import ConfigError
from monitor.zones.schema import CameraSpec, CellSpec
from monitor.zones.validate import _check_spec, _pydantic_message

if TYPE_CHECKING:
    from monitor.zones.prepare import PreparedCell

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
    def label(self) -> str:
        return str(self.path) if self.path is not None else "<cell>"

    @cached_property
    def prepared(self) -> PreparedCell:
        """Geometry built once for the per-frame queries (cached on this object)."""
        from monitor.zones.prepare import prepare_cell  # prepare needs Cell: import late

        return prepare_cell(self)


def load_cell(path: str | os.PathLike) -> Cell:
    """Read and validate a zone file; raises ConfigError (one line) on any fault."""
    return parse_cell(read_cell_data(path), path)


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses a key given twice in one mapping (PyYAML keeps the last one
    silently, which could switch a zone's kind or enabled flag unnoticed)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


def _read_yaml(path: str | os.PathLike, load: Any, errors: tuple[type[Exception], ...]) -> Any:
    """Read a zone file and parse it with ``load(text)``; one-line ConfigError on any fault,
    with the line and column of a YAML syntax error."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: zone file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read zone file: {exc}") from None
    try:
        return load(text)
    except errors as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{p}{where}: YAML syntax error: {problem}") from None


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


def dump_cell_document(document: Any) -> str:
    from ruamel.yaml import YAML

    out = io.StringIO()
    yaml_rt = YAML(typ="rt")
    yaml_rt.width = 100
    yaml_rt.indent(mapping=2, sequence=4, offset=2)  # "key:\n  - item", as zones/ files are
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
        spec = CellSpec.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{label}: {_pydantic_message(exc, data)}") from None
    base = Path(path).parent if path is not None else Path.cwd()
    errors, warnings, models, meshes = _check_spec(spec, base)
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
        spec = CellSpec.model_validate(data)
    except ValidationError as exc:
        return [_pydantic_message(exc, data, index=k) for k in range(len(exc.errors()))], []
    base = Path(path).parent if path is not None else Path.cwd()
    errors, warnings, _, _ = _check_spec(spec, base)
    return errors, warnings


def cell_to_data(cell_or_spec: Cell | CellSpec) -> dict:
    """Plain data (lists, dicts, numbers) of a cell, as it is written to YAML."""
    spec = cell_or_spec.spec if isinstance(cell_or_spec, Cell) else cell_or_spec
    return spec.model_dump(mode="json", exclude_none=True)


class _Dumper(yaml.SafeDumper):
    """Lists of numbers in flow style ([x, y]) so that polygons stay readable."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(not isinstance(v, list | dict) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def dump_cell_yaml(cell_or_spec: Cell | CellSpec) -> str:
    header = ("# workcell-monitor zone file (format: zones/README.md). Written by "
              "'monitor zones new'.\n")
    body = yaml.dump(cell_to_data(cell_or_spec), Dumper=_Dumper, sort_keys=False,
                     allow_unicode=True, width=100)
    return header + body


def save_cell(cell: Cell, path: str | os.PathLike, document: Any = None) -> None:
    """Write the cell atomically: a temp file in the same directory is renamed over ``path``;
    an existing file is first copied to ``path.bak``. With ``document`` (from
    :func:`read_cell_document`, already validated as ``cell``) the file keeps its comments."""
    target = Path(path)
    text = dump_cell_document(document) if document is not None else dump_cell_yaml(cell)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        if target.exists():
            shutil.copymode(target, tmp)
        else:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        if target.exists():
            bak_tmp = target.with_name(f".{target.name}.bak.tmp")
            shutil.copy2(target, bak_tmp)
            os.replace(bak_tmp, target.with_name(target.name + ".bak"))
        os.replace(tmp, target)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise ConfigError(f"{target}: cannot write zone file: {exc}") from None


def write_cell_data(data: Any, path: str | os.PathLike) -> Cell:
    """Validate zone-file data and, only when valid, save it atomically to ``path`` (the
    previous file is kept as ``path.bak``). On a fault nothing is written."""
    from ruamel.yaml.comments import CommentedMap

    cell = parse_cell(data, path)
    save_cell(cell, path, data if isinstance(data, CommentedMap) else None)
    return cell


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
        "cameras": sorted((c.model_dump(mode="json") for c in spec.cameras),
                          key=lambda c: c["id"]),
        "zones": sorted(zones, key=lambda z: z["id"]),
        "person": spec.person.model_dump(mode="json"),
        "separation": spec.separation.model_dump(mode="json"),
        "tool": tool,
    }
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


