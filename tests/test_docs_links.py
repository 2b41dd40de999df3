"""The README stays short and every relative link in the documentation leads somewhere.

README.md is the front page: the two set-up commands, the safety notice, the stage map, the
everyday commands and an index into docs/, where everything else is written out. A link that
points at a moved or renamed page (or at a heading that changed) is a dead end for the reader, so
every relative link in README.md, docs/*.md, models/README.md and zones/*.md must name an
existing file, and an anchor (``page.md#heading``) a heading of that page as GitHub renders it.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README_MAX_LINES = 200
SETUP = ("```sh\n"
         "python3 -m venv .venv && .venv/bin/pip install -e '.[test]' && .venv/bin/monitor demo\n"
         ".venv/bin/python -m pytest\n"
         "```\n")

FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.MULTILINE | re.DOTALL)
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1", re.DOTALL)
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.MULTILINE)
HTML_ANCHOR = re.compile(r"<a\s+(?:id|name)=\"([^\"]+)\"", re.IGNORECASE)
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def documents() -> list[Path]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
             ROOT / "models" / "README.md", *sorted((ROOT / "zones").glob("*.md"))]
    return [f for f in files if f.is_file()]


def prose(text: str) -> str:
    """The text without fenced code blocks: a `# comment` there is no heading and a `[x](y)`
    there no link."""
    return FENCE.sub("", text)


def links(text: str) -> list[str]:
    # code spans become a word, so a link whose text is code (`[`a.md`](a.md)`) still counts
    # and a `](` inside code does not
    return LINK.findall(CODE_SPAN.sub("code", prose(text)))


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: the rendered text lower-cased, punctuation dropped, each
    space a hyphen."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link renders as its text
    text = re.sub(r"[*`]", "", text).strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = prose(path.read_text(encoding="utf-8"))
    seen: dict[str, int] = {}
    out = set(HTML_ANCHOR.findall(text))
    for heading in HEADING.findall(text):
        base = slug(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def broken_links(path: Path, root: Path = ROOT) -> list[str]:
    out = []
    for target in links(path.read_text(encoding="utf-8")):
        if SCHEME.match(target):
            continue  # http(s), mailto: not ours to check offline
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / file_part).resolve() if file_part else path
        where = f"{path.relative_to(root)}: ({target})"
        if not dest.is_relative_to(root):
            out.append(f"{where} leaves the repository")
        elif not dest.exists():
            out.append(f"{where} names a missing file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            out.append(f"{where} names no heading of {dest.relative_to(root)}")
    return out


@pytest.mark.parametrize("path", documents(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_names_an_existing_file_and_heading(path):
    assert broken_links(path) == []


def test_the_readme_is_short_and_starts_with_the_set_up_commands():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) < README_MAX_LINES, "README.md: move detail into docs/"
    assert text.startswith("# workcell-monitor\n\n" + SETUP)
    assert "> **Safety notice.**" in text


def test_every_docs_page_has_a_title_for_monitor_docs():
    # `monitor docs` lists each page by its first heading
    for page in sorted((ROOT / "docs").glob("*.md")):
        assert page.read_text(encoding="utf-8").startswith("# "), page.name


def test_the_link_checker_sees_links_anchors_and_code(tmp_path):
    """The checker itself: a dead file, a dead anchor and a link that leaves the checkout are
    found; links in code are not links; GitHub's slugs for code, punctuation and repeats."""
    (tmp_path / "b.md").write_text("# The `monitor replay` command\n## Ports: 7447/tcp\n"
                                   "## Again\n## Again\n```sh\n# not a heading\n```\n")
    page = tmp_path / "a.md"
    page.write_text("[ok](b.md) [ok](b.md#the-monitor-replay-command) [ok](b.md#again-1) "
                    "[ok](b.md#ports-7447tcp) [`b.md`](b.md) [web](https://example.org/x) "
                    "[gone](c.md) [bad](b.md#not-a-heading) [out](../x.md) `[code](d.md)`\n"
                    "```\n[fenced](e.md)\n```\n")
    found = broken_links(page, tmp_path)
    assert [f.split("(")[1].split(")")[0] for f in found] == ["c.md", "b.md#not-a-heading",
                                                              "../x.md"]
