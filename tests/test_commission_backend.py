"""The commissioning report names the detector backend and precision that run the model and
how their persons agree with onnxruntime's, from the running service's status (the status
field is ``Choice.to_dict``, monitor/detector/choice.py), and says so when no status is given."""

from __future__ import annotations

import json
import re
from html import unescape
from pathlib import Path

from monitor.cli import main
from monitor.detector.choice import open_detector
from tests.helpers import commissioner_key


def _model_rows(html: str) -> str:
    section = re.search(r'id="model".*?</section>', html, re.S)
    assert section is not None, "the report has no model section"
    return " ".join(unescape(re.sub(r"<[^>]+>", " ", section.group(0))).split())


def _report(tmp_path: Path, name: str, *args: str) -> str:
    out = tmp_path / name
    key = commissioner_key(tmp_path, "anna")
    assert main(["commission", "report", "--out", str(out), "--by", "anna", "--key", str(key),
                 *args]) == 0
    return _model_rows(out.read_text())


def test_the_report_names_the_backend_that_runs(tmp_path, synthetic_model):
    _, choice = open_detector(synthetic_model)  # what `monitor run` chooses on this host
    status = tmp_path / "status.json"
    status.write_text(json.dumps({"detector": choice.to_dict()}))
    rows = _report(tmp_path, "with.html", "--status", str(status))
    agreement = choice.agreement.agreement if choice.agreement is not None else 1.0
    assert (f"backend that runs it {choice.chosen.backend} {choice.chosen.precision}, "
            f"agreement {agreement:.3f} with onnxruntime's persons ({choice.reason})") in rows


def test_without_a_status_the_report_says_where_it_comes_from(tmp_path):
    rows = _report(tmp_path, "without.html")
    assert "backend that runs it" in rows and "--status status.json" in rows
