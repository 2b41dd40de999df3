"""A zone file's own indentation, so that an edit rewrites only what it changes.

ruamel.yaml writes with the indentation it is told; without this an edit of a file indented by
4 (or with sequences flush under their key) would re-indent every line, and a review of the
change (``diff FILE.bak FILE``) would show the whole file.
"""

from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class Indent:
    """ruamel.yaml's ``indent(mapping, sequence, offset)``: a nested mapping's indentation, a
    sequence item's content and its dash, each relative to the parent key."""

    mapping: int = 2
    sequence: int = 4
    offset: int = 2  # the project's style: "key:\n  - item" (zones/demo-cell.yaml)


# a key with no value on its line (a block mapping or sequence follows), optionally a sequence
# item's first key: "  key:", "  - key:  # comment"
_KEY_ONLY = re.compile(r"^( *)((?:- +)*)([^\s#\-\[{'\"][^#]*?|'[^']*'|\"[^\"]*\"):\s*(?:#.*)?$")


def guess_indent(text: str) -> Indent:
    """The indentation a YAML text uses (the first nested mapping and the first block sequence
    under a key tell); the project's default for what the text does not show."""
    mapping = sequence = offset = None
    parent: int | None = None  # column of the last key-only line's key
    for line in text.splitlines():
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        column = len(line) - len(line.lstrip(" "))
        item = stripped.startswith("- ")
        # a sequence may sit flush under its key ("key:\n- item"): offset 0
        if parent is not None and (column > parent or (item and column == parent)):
            if item:
                if offset is None:
                    offset = column - parent
                    content = column + 1 + len(stripped[1:]) - len(stripped[1:].lstrip(" "))
                    sequence = content - parent
            elif mapping is None:
                mapping = column - parent
        if mapping is not None and offset is not None:
            break
        m = _KEY_ONLY.match(line)
        parent = len(m.group(1)) + len(m.group(2)) if m else None
    if offset is not None and sequence is not None and sequence < offset + 2:
        sequence = offset + 2  # ruamel needs room for "- "
    default = Indent()
    return Indent(mapping or default.mapping,
                  sequence if sequence is not None else default.sequence,
                  offset if offset is not None else default.offset)
