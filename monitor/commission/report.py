"""The commissioning report: one self-contained, printable HTML file (pictures as data URIs, no
script, no outside resource) rendered from ``inputs.gather``'s content. Pure and deterministic:
keys sorted, no clock (the date is what the sign-off gives).

Its first page is what a signer decides on: the verdict per zone and camera with every reason,
and every open warning. The details follow (``report_details``), the sign-off with the
signature block on the last page. A4 print styles with page numbers.

It is signed over every byte with the commissioner's Ed25519 key (``monitor.wire.evidence``):
the file ends in a fixed signature block (``REPORT_LAYOUT``: the signer's public key and the
signature, found by position from the end, inside the sign-off section on the last page), and
the signature covers every other byte, so ``verify`` fails on any added, removed or changed
byte, wherever it is.
"""

from __future__ import annotations

import re
from html import escape

from monitor.commission import report_details as d
from monitor.commission.html import items, section, table
from monitor.wire.evidence import Layout, Opened, open_signed, sign
from monitor.wire.signing import Signer

SECTIONS = ("summary", "warnings", "identity", "model", "zones", "zone-sets", "pictures",
            "unseen", "calibration", "settings", "keys", "separation", "capacity", "reaction",
            "walk", "not-tested", "signoff")
REPORT_LAYOUT = Layout(
    "commissioning-report",
    b'<p class="signature">Ed25519 signature of every byte of this file but the 88 characters '
    b'of the signature itself, by key <code id="signature-key">',
    b'</code>: <code id="signature">',
    b"</code></p>\n</section>\n</body>\n</html>\n")
SIGNER = re.compile(r'<span id="signer">([^<]*)</span>')

STYLE = """
body { font-family: sans-serif; font-size: 10.5pt; margin: 2em auto; max-width: 180mm;
       color: #111; }
h1 { font-size: 17pt; } h2 { font-size: 13.5pt; border-bottom: 1px solid #888;
  margin-top: 1.4em; } h3 { font-size: 12pt; } h4 { font-size: 11pt; margin-bottom: 0.2em; }
table { border-collapse: collapse; margin: 0.4em 0; }
td, th { border: 1px solid #aaa; padding: 2px 5px; text-align: left; vertical-align: top; }
table.small td, table.small th { font-size: 8.5pt; }
code { font-size: 8.5pt; word-break: break-all; }
img { max-width: 100%; border: 1px solid #888; }
figure { margin: 0.6em 0; break-inside: avoid; }
.warn { color: #a00; } .note { color: #333; }
.PASS { color: #060; font-weight: bold; } .FAIL { color: #a00; font-weight: bold; }
.sign td { height: 2.2em; min-width: 16em; }
.signature { font-size: 8pt; }
@page { size: A4; margin: 16mm 14mm 18mm 14mm;
  @bottom-left { content: "workcell-monitor commissioning report"; font-size: 8pt; }
  @bottom-right { content: "page " counter(page) " of " counter(pages); font-size: 8pt; } }
@media print {
  body { margin: 0; max-width: none; }
  .details { break-before: page; }
  #signoff { break-before: page; }
  table, tr, figure, h2, h3, h4 { break-inside: avoid; }
  h2, h3, h4 { break-after: avoid; }
}
"""


def render(content: dict) -> str:
    """The report's HTML up to its signature block (``signed`` adds it)."""
    cell = escape(str(content.get("cell") or ""))
    parts = [
        "<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
        f"<title>Commissioning report: cell {cell}</title>", f"<style>{STYLE}</style>",
        "</head>", "<body>", f"<h1>Commissioning report: cell {cell}</h1>",
        "<p>workcell-monitor is a supplementary monitor, not a certified protective device.</p>",
        _summary(content), _warnings(content["warnings"]),
        '<div class="details">', d.identity(content), "</div>",
        d.model(content["model"]), d.zones(content["zones"], content["zone_details"]),
        d.zone_sets(content["zone_sets"]), d.pictures(content["pictures"]),
        d.unseen(content.get("unseen") or []),
        d.calibration(content["calibration"]), d.settings(content["settings"]),
        d.keys(content["keys"]),
        d.separation(content["person"], content["reaction"], content["zone_details"]),
        d.capacity(content["capacity"]), d.reaction(content["reaction"], content["budget"]),
        d.walks(content["walks"]), d.not_tested(content["not_tested"]),
        _signoff(content["signoff"]), ""]
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


def _verdict_rows(verdicts: list[dict]) -> list[str]:
    rows = []
    for v in verdicts:
        reasons = "; ".join(v["reasons"]) or "&mdash;"
        rows.append(f'<tr><td>{escape(v["what"])} {escape(v["subject"])}</td>'
                    f'<td class="{v["verdict"]}">{v["verdict"]}</td>'
                    f"<td>{escape(reasons) if v['reasons'] else reasons}</td></tr>")
    return rows


def _summary(c: dict) -> str:
    v = c["verdicts"]
    everything = v["zones"] + v["cameras"]
    overall = "FAIL" if not everything or any(x["verdict"] == "FAIL" for x in everything) \
        else "PASS"
    f = c["fingerprint"]
    ident = table([("configuration", c["config"]["file"]), ("zone set", f["zones_hash"]),
                   ("model SHA-256", f["model_sha256"][:16] + "..."),
                   ("walks", len(c["walks"])),
                   ("floor a walk must cover", f"{100 * v['min_walked']:.0f} % of each "
                    "zone's visible floor")])
    rows = "\n".join(["<table>", "<tr><th>zone or camera</th><th>walk test</th>"
                      "<th>why</th></tr>", *_verdict_rows(everything), "</table>"])
    return section("summary", "Verdict",
                   f'<p>Walk test overall: <strong class="{overall}">{overall}</strong> '
                   f"({sum(x['verdict'] == 'PASS' for x in everything)} of {len(everything)} "
                   "pass). A FAIL names what the walk did not show; sign only when every "
                   "zone passes or each FAIL and warning is accepted below.</p>", rows, ident)


def _warnings(warnings: list[str]) -> str:
    body = items(warnings) if warnings else "<p>None.</p>"
    return section("warnings", f"Open warnings ({len(warnings)})", body)


def _signoff(s: dict) -> str:
    rows = [("commissioned by", s.get("commissioned_by") or ""), ("date", s.get("date") or ""),
            ("signature", ""), ("accepted by (operator of the cell)", ""), ("date", ""),
            ("signature", "")]
    key = s.get("key") or {}
    return "\n".join([
        '<section id="signoff">', "<h2>Sign-off</h2>",
        "<p>The undersigned commissioned the cell with the configuration identified above, "
        "read the verdict and every open warning on the first page, and accept it as shown."
        "</p>",
        table(rows, css="sign"),
        f'<p>Signed digitally by <span id="signer">{escape(s.get("commissioned_by") or "")}'
        f"</span> (commissioner key {escape(str(key.get('fingerprint') or ''))}). Check it "
        "with <code>monitor commission verify REPORT --config monitor.toml</code>: any "
        "changed byte fails.</p>"])
