"""The commissioning report: one self-contained, printable HTML file (pictures as data URIs, no
script, no outside resource) rendered from ``inputs.gather``'s content. Pure and deterministic:
keys sorted, no clock (the date is what the sign-off gives).

It is signed over every byte with the commissioner's Ed25519 key (``monitor.wire.evidence``):
the file ends in a fixed signature block (``REPORT_LAYOUT``: the signer's public key and the
signature, found by position from the end, inside the sign-off section on the last page), and
the signature covers every other byte, so ``verify`` fails on any added, removed or changed
byte, wherever it is.
"""

from __future__ import annotations

import json
import re
from html import escape
from typing import Any

from monitor.wire.evidence import Layout, Opened, open_signed, sign
from monitor.wire.signing import Signer

SECTIONS = ("identity", "model", "zones", "pictures", "settings", "keys", "capacity",
            "reaction", "walk", "warnings", "signoff")
REPORT_LAYOUT = Layout(
    "commissioning-report",
    b'<p class="signature">Ed25519 signature of every byte of this file but the 88 characters '
    b'of the signature itself, by key <code id="signature-key">',
    b'</code>: <code id="signature">',
    b"</code></p>\n</section>\n</body>\n</html>\n")
SIGNER = re.compile(r'<span id="signer">([^<]*)</span>')

STYLE = """
body { font-family: sans-serif; font-size: 11pt; margin: 2em; color: #111; }
h1 { font-size: 18pt; } h2 { font-size: 14pt; border-bottom: 1px solid #888; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.4em 0; }
td, th { border: 1px solid #aaa; padding: 2px 6px; text-align: left; vertical-align: top; }
code { font-size: 9pt; word-break: break-all; }
img { max-width: 100%; border: 1px solid #888; }
figure { margin: 0.6em 0; page-break-inside: avoid; }
.warn { color: #a00; } .sign td { height: 2.2em; min-width: 16em; }
@media print { body { margin: 0; } section { page-break-inside: avoid; } }
"""


def render(content: dict) -> str:
    """The report's HTML up to its signature block (``signed`` adds it)."""
    cell = escape(str(content.get("cell") or ""))
    parts = [
        "<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
        f"<title>Commissioning report: cell {cell}</title>", f"<style>{STYLE}</style>",
        "</head>", "<body>", f"<h1>Commissioning report: cell {cell}</h1>",
        "<p>workcell-monitor is a supplementary monitor, not a certified protective device.</p>",
        _identity(content), _model(content["model"]), _zones(content["zones"]),
        _pictures(content["pictures"]), _settings(content["settings"]), _keys(content["keys"]),
        _capacity(content["capacity"]), _reaction(content["reaction"]),
        _walk(content["walk"]), _warnings(content["warnings"]), _signoff(content["signoff"]),
        ""]
    return "\n".join(parts)


def signed(body: str, signer: Signer) -> bytes:
    """The report file: ``body`` and its signature block."""
    return sign(body.encode("utf-8"), REPORT_LAYOUT, signer)


def verify(data: bytes) -> Opened:
    """The report taken apart and checked (``evidence.NotSigned`` when it has no signature
    block at its end)."""
    return open_signed(data, REPORT_LAYOUT)


def signer_named(opened: Opened) -> str | None:
    """The name the (signed) sign-off gives the signer."""
    found = SIGNER.search(opened.body.decode("utf-8", "replace"))
    return found.group(1) if found else None


# --- sections ------------------------------------------------------------------------------------

def _section(sid: str, title: str, *body: str) -> str:
    return "\n".join([f'<section id="{sid}">', f"<h2>{escape(title)}</h2>", *body,
                      "</section>"])


def _table(rows: list[tuple[Any, ...]], head: tuple[str, ...] = ()) -> str:
    out = ["<table>"]
    if head:
        out.append("<tr>" + "".join(f"<th>{escape(h)}</th>" for h in head) + "</tr>")
    for row in rows:
        out.append("<tr>" + "".join(f"<td>{_cell(v)}</td>" for v in row) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _cell(value: Any) -> str:
    if value is None:
        return "&mdash;"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict | list):
        return f"<code>{escape(json.dumps(value, sort_keys=True))}</code>"
    return escape(str(value))


def _code(value: Any) -> str:
    return f"<code>{escape(str(value))}</code>" if value else "&mdash;"


def _identity(c: dict) -> str:
    f = c["fingerprint"]
    rows = [("product", f"{c['product']['name']} {c['product']['version']}"),
            ("configuration file", c["config"]["file"]),
            ("configuration file SHA-256", c["config"]["sha256"]),
            ("zone set (config_hash)", f["zones_hash"]), ("model SHA-256", f["model_sha256"]),
            ("changed settings SHA-256", f["settings_sha256"])]
    return _section("identity", "Identity",
                    "<p>The running monitor compares these three digests with this report's "
                    "record (<code>monitor status</code>: <code>commissioned</code>).</p>",
                    _table(rows))


def _model(m: dict) -> str:
    rows = [("file", m["file"]), ("SHA-256", m["sha256"]),
            ("measured envelope", m["envelope_file"] or "none measured")]
    env = m.get("envelope") or {}
    rows += [(f"envelope: {k}", v) for k, v in sorted(env.items())]
    return _section("model", "Detector model", _table(rows))


def _zones(z: dict | None) -> str:
    if z is None:
        return _section("zones", "Zones", "<p class=\"warn\">No zone file.</p>")
    head = _table([("file", z["file"]), ("file SHA-256", z["sha256"]),
                   ("zone set (config_hash)", z["config_hash"])])
    cams = _table([(c["id"], c["size"], "yes" if c["calibrated"] else "no")
                   for c in z["cameras"]], ("camera", "size", "calibrated"))
    zones = _table([(x["id"], x["kind"], x["shape"], "yes" if x["enabled"] else "no")
                    for x in z["zones"]], ("zone", "kind", "shape", "enabled"))
    return _section("zones", "Zones", head, cams, zones)


def _figures(pictures: dict[str, str]) -> list[str]:
    return [f'<figure><img alt="{escape(name)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{escape(name)}</figcaption></figure>"
            for name, data in sorted(pictures.items())]


def _pictures(pictures: dict[str, str]) -> str:
    return _section("pictures", "Zones drawn", "<p>Every zone on each camera's reference image "
                    "and on the floor plan (cell coordinates, metres, x right, y up; the robot "
                    "base at the cross). Red: floor no camera can see a person on.</p>",
                    *_figures(pictures))


def _settings(settings: dict) -> str:
    body = _table(sorted(settings.items()), ("setting", "value")) if settings else \
        "<p>Every setting is at its default.</p>"
    return _section("settings", "Settings that differ from the defaults", body)


def _keys(k: dict) -> str:
    mon = k["monitor"]
    rows = [("monitor command key", f"{mon['fingerprint']} ({mon['public_key']})"
             if mon else "none: commands are not signed"),
            ("resets without a key", "accepted" if k["unsigned_resets"] else "refused")]
    ops = _table([(o["operator"], o["fingerprint"]) for o in k["operators"]],
                 ("operator", "key fingerprint")) if k["operators"] else \
        "<p>No operators file: nobody can reset with a key.</p>"
    return _section("keys", "Keys and operators", _table(rows), ops)


def _capacity(cap: dict | None) -> str:
    if not cap:
        return _section("capacity", "Capacity check",
                        "<p class=\"warn\">Not given: pass the running service's status "
                        "(<code>monitor status --json &gt; status.json</code>, "
                        "<code>--status status.json</code>).</p>")
    rows = [(k, v) for k, v in sorted(cap.items()) if k != "cameras"]
    cams = _table([(c, v.get("fps"), v.get("frame_age_ms"))
                   for c, v in sorted((cap.get("cameras") or {}).items())],
                  ("camera", "processed fps", "worst frame age (ms)"))
    return _section("capacity", "Capacity check", _table(rows), cams)


def _reaction(r: dict) -> str:
    rows = [("T_r of this configuration (s)", r["configured_s"]),
            ("programmed tool speed (m/s)", r["programmed_speed_mps"]),
            ("S_p at that T_r (m)", r["s_p_configured_m"])]
    measured = _table([(cam, m["measured_s"], m["s_p_m"], "yes" if m["exceeded"] else "no")
                       for cam, m in sorted(r["measured"].items())],
                      ("camera", "measured T_r (s)", "S_p it implies (m)", "exceeds T_r")) \
        if r["measured"] else "<p class=\"warn\">No measured reaction time (no status given)."\
        "</p>"
    return _section("reaction", "Reaction time and separation", _table(rows), measured)


def _walk(w: dict | None) -> str:
    if w is None:
        return _section("walk", "Walk test", "<p class=\"warn\">No walk test given.</p>")
    head = _table([("video", w.get("video")), ("camera", w.get("camera")),
                   ("duration (s)", w.get("duration_s")), ("frames", w.get("frames")),
                   ("floor cell (m)", w.get("cell_m")), ("zone set", w.get("zones_hash")),
                   ("entries counted from", f"ground truth ({w['truth']}) and detections"
                    if w.get("truth") else "detections")])
    body = [head]
    for z in w.get("zones", []):
        cover = _table([("floor cells", z["cells"]),
                        ("cells a camera sees", f"{z['visible_cells']} ({_pct(z, 'visible')})"),
                        ("cells the person was seen in", f"{z['seen_cells']} "
                         f"({_pct(z, 'seen')})"),
                        ("blind spots (cell centres, m)", len(z["blind_spots"])),
                        ("gaps in detection", len(z["gaps"]))])
        entries = _table([(k + 1, e["entry_s"], e["exit_s"], e["stop_s"], e["time_to_stop_s"],
                           e["frames_inside"], e.get("detected_s"))
                          for k, e in enumerate(z["entries"])],
                         ("entry", "in at (s)", "out at (s)", "STOP at (s)", "time to STOP (s)",
                          "frames inside", "first detected in (s)")) \
            if z["entries"] else "<p>No entry.</p>"
        corners = _table([(f"({c['corner_m'][0]:g}, {c['corner_m'][1]:g})", c["blind_cells"],
                           "-" if c["frames_near"] is None else c["frames_near"],
                           c["frames_seen"]) for c in z.get("corners", [])],
                         ("corner (m)", "blind cells within 0.5 m", "frames there (truth)",
                          "frames seen there")) if z.get("corners") else ""
        blind = (f"<p>Blind spots: {escape(_points(z['blind_spots']))}</p>"
                 if z["blind_spots"] else "")
        gaps = _table([(g["from_s"], g["to_s"], g["duration_s"], g["frames_missed"])
                       for g in z["gaps"]], ("from (s)", "to (s)", "length (s)",
                                             "frames missed")) if z["gaps"] else ""
        body += [f'<h3 id="walk-{escape(z["zone_id"])}">{escape(z["kind"])} zone '
                 f'{escape(z["zone_id"])}</h3>', cover, entries, corners, blind, gaps]
    body += _figures(w.get("pictures") or {})
    return _section("walk", "Walk test", *[b for b in body if b])


def _pct(z: dict, what: str) -> str:
    value = z.get(f"{what}_fraction")
    return "no floor" if value is None else f"{100 * value:.0f} %"


def _points(points: list) -> str:
    return ", ".join(f"({x:g}, {y:g})" for x, y in points)


def _warnings(warnings: list[str]) -> str:
    body = "<ul>" + "".join(f'<li class="warn">{escape(w)}</li>' for w in warnings) + "</ul>" \
        if warnings else "<p>None.</p>"
    return _section("warnings", "Open warnings", body)


def _signoff(s: dict) -> str:
    rows = [("commissioned by", s.get("commissioned_by") or ""), ("date", s.get("date") or ""),
            ("signature", ""), ("accepted by (operator of the cell)", ""), ("date", ""),
            ("signature", "")]
    key = s.get("key") or {}
    return "\n".join([
        '<section id="signoff">', "<h2>Sign-off</h2>",
        "<p>The undersigned commissioned the cell with the configuration identified above and "
        "accept it as shown.</p>",
        _table(rows).replace("<table>", '<table class="sign">', 1),
        f'<p>Signed digitally by <span id="signer">{escape(s.get("commissioned_by") or "")}'
        f"</span> (commissioner key {escape(str(key.get('fingerprint') or ''))}). Check it "
        "with <code>monitor commission verify REPORT --config monitor.toml</code>: any "
        "changed byte fails.</p>"])
