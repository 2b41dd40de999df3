"""The few HTML pieces the report is made of (pure, every value escaped)."""

from __future__ import annotations

import json
from html import escape
from typing import Any


def section(sid: str, title: str, *body: str, css: str = "") -> str:
    cls = f' class="{css}"' if css else ""
    return "\n".join([f'<section id="{sid}"{cls}>', f"<h2>{escape(title)}</h2>",
                      *[b for b in body if b], "</section>"])


def table(rows: list[tuple[Any, ...]], head: tuple[str, ...] = (), css: str = "") -> str:
    out = [f'<table class="{css}">' if css else "<table>"]
    if head:
        out.append("<tr>" + "".join(f"<th>{escape(h)}</th>" for h in head) + "</tr>")
    for row in rows:
        out.append("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in row) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def cell(value: Any) -> str:
    if value is None:
        return "&mdash;"
    if isinstance(value, Raw):
        return value.html
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict | list):
        return f"<code>{escape(json.dumps(value, sort_keys=True))}</code>"
    return escape(str(value))


class Raw:
    """Markup already escaped, put in a table cell as it is."""

    def __init__(self, html: str) -> None:
        self.html = html


def code(value: Any) -> str:
    return f"<code>{escape(str(value))}</code>" if value else "&mdash;"


def items(lines: list[str], css: str = "warn") -> str:
    return "<ul>" + "".join(f'<li class="{css}">{escape(x)}</li>' for x in lines) + "</ul>"


def points(pts: list) -> str:
    return ", ".join(f"({x:g}, {y:g})" for x, y in pts)
