"""No private (underscore) name of monitor/ is used outside its own module
(docs/architecture.md, "Layers"): what another module needs is public, so renaming or changing
a private helper never breaks a caller its author cannot see. The check walks monitor/ with
``ast``; a package's ``__init__`` importing a private name from one of its own submodules counts
as across modules too."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_module(dotted: str, root: Path) -> bool:
    base = root.joinpath(*dotted.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def _absolute(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    """The absolute module an ``ImportFrom`` names (relative imports resolved)."""
    if not node.level:
        return node.module or ""
    base = module.split(".")
    keep = len(base) - node.level + (1 if is_package else 0)
    return ".".join(base[:keep] + ([node.module] if node.module else []))


def private_uses(root: Path) -> list[str]:
    """``file:line: what`` for every private name of a monitor module used by another module.
    ``root`` holds the ``monitor`` package."""
    found = []
    for path in sorted((root / "monitor").rglob("*.py")):
        module = _module_name(path, root)
        is_package = path.name == "__init__.py"
        tree = ast.parse(path.read_text(), filename=str(path))
        where = path.relative_to(root)
        aliases: dict[str, str] = {}  # local name -> the monitor module it is bound to
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("monitor"):
                        aliases[a.asname or a.name.split(".")[0]] = \
                            a.name if a.asname else a.name.split(".")[0]
                        if any(_private(p) for p in a.name.split(".")) and a.name != module:
                            found.append(f"{where}:{node.lineno}: import {a.name}")
            elif isinstance(node, ast.ImportFrom):
                source = _absolute(node, module, is_package)
                if not source.startswith("monitor"):
                    continue
                for a in node.names:
                    submodule = _is_module(f"{source}.{a.name}", root)
                    if submodule:
                        aliases[a.asname or a.name] = f"{source}.{a.name}"
                    # a private submodule is another module even for its package's __init__
                    if _private(a.name) and (source != module or submodule):
                        found.append(f"{where}:{node.lineno}: from {source} import {a.name}")
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and _private(node.attr):
                owner = _dotted(node.value, aliases)
                if owner and owner != module and _is_module(owner, root):
                    found.append(f"{where}:{node.lineno}: {owner}.{node.attr}")
    return found


def _dotted(node: ast.expr, aliases: dict[str, str]) -> str | None:
    """The monitor module an expression like ``calibration`` or ``monitor.geometry`` names."""
    if isinstance(node, ast.Name):
        return aliases.get(node.id)
    if isinstance(node, ast.Attribute):
        owner = _dotted(node.value, aliases)
        return f"{owner}.{node.attr}" if owner else None
    return None


def test_no_module_of_monitor_uses_another_modules_private_name():
    found = private_uses(ROOT)
    assert not found, "private names used across modules (make them public or keep them " \
        "in one module):\n" + "\n".join(found)


def test_the_checker_names_each_kind_of_private_use_in_a_scratch_tree(tmp_path):
    pkg = tmp_path / "monitor" / "geometry"
    pkg.mkdir(parents=True)
    for name in ("monitor/__init__.py", "monitor/geometry/boxes.py", "monitor/geometry/polygons.py",
                 "monitor/geometry/camera.py", "monitor/geometry/poses.py"):
        (tmp_path / name).write_text("def _helper():\n    return 0\n")
    (pkg / "scratch.py").write_text(
        "from monitor.geometry.polygons import points_in_polygon, _helper\n"
        "from . import camera\n"
        "import monitor.geometry.poses as poses\n"
        "import monitor.geometry.boxes\n\n\n"
        "def _own():\n    return 1\n\n\n"
        "def use():\n"
        "    return (camera._hidden, poses._other, monitor.geometry.boxes._deep, _own(),\n"
        "            points_in_polygon, _helper)\n")
    (pkg / "__init__.py").write_text("from monitor.geometry.scratch import _own, use\n"
                                     "from .camera import _helper as helper\n")
    found = private_uses(tmp_path)
    assert sorted(found) == sorted([
        "monitor/geometry/__init__.py:1: from monitor.geometry.scratch import _own",
        "monitor/geometry/__init__.py:2: from monitor.geometry.camera import _helper",
        "monitor/geometry/scratch.py:1: from monitor.geometry.polygons import _helper",
        "monitor/geometry/scratch.py:12: monitor.geometry.camera._hidden",
        "monitor/geometry/scratch.py:12: monitor.geometry.poses._other",
        "monitor/geometry/scratch.py:12: monitor.geometry.boxes._deep",
    ]), found  # a module's own private names (_own in scratch.py) are its own business
