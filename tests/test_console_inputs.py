"""Issue 31, part 3: every bad input to the zone editor is a 400 with a one-line message and an
audit line (and, for an operator, a ``zone_edit`` incident), never a 500; the zone file is
untouched. Real HTTP through Starlette's test client against the real app."""

from __future__ import annotations

import json

import pytest
from starlette.testclient import TestClient

from monitor.console.app import build_app
from monitor.incidents import IncidentIndex
from tests.console_kit import OPERATOR, PASSWORD, basic, make_console

SQUARE = [[900, 150], [1200, 150], [1200, 400], [900, 400]]
JSON = {"content-type": "application/json", **basic(OPERATOR, PASSWORD)}


def _body(**fields) -> bytes:
    return json.dumps({"camera": "cam0", "kind": "protective", "points_px": SQUARE,
                       **fields}).encode()


def _points(first: str) -> bytes:
    """Raw JSON with ``first`` as the first point's x, as a client could send it."""
    return ('{"camera": "cam0", "kind": "protective", "points_px": [[' + first +
            ', 150], [1200, 150], [1200, 400], [900, 400]]}').encode()


CASES = [
    pytest.param(_points("1" + "0" * 400), "out of range", id="10^400-integer"),
    pytest.param(_points("1e400"), "out of range", id="1e400-float"),
    pytest.param(_points("NaN"), "NaN: not a number", id="NaN"),
    pytest.param(_points("-Infinity"), "-Infinity: not a number", id="-Infinity"),
    pytest.param(_body(speed_scale=1e300, kind="warning"), "out of range", id="speed-1e300"),
    pytest.param(b'{"points_px": ' + b"[" * 100_000 + b"]" * 100_000 + b"}",
                 "nested too deeply", id="deep-100000"),
    pytest.param(b'{"points_px": ' + b"[" * 50 + b"]" * 50 + b"}", "nested too deeply",
                 id="deep-50"),
    pytest.param(_body(name="x" * 1_000_000), "at most 256000", id="1MB-string"),
    pytest.param(_body(name="x" * 200_000), "name: at most 200 characters", id="200kB-name"),
    pytest.param(_body(camera=["cam0"]), "camera: a text", id="camera-list"),
    pytest.param(_body(speed_scale="fast"), "speed_scale: a number", id="speed-text"),
    pytest.param(_body(evil=1), "unknown field 'evil'", id="unknown-field"),
    pytest.param(b"[1, 2]", "not a JSON object", id="array"),
    pytest.param(b"{\"points_px\": ", "not JSON", id="truncated"),
    pytest.param(b"\xff\xfe\x00", "not JSON", id="not-utf8"),
]


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("inputs")
    return TestClient(build_app(make_console(tmp))), tmp


@pytest.mark.parametrize(("raw", "needle"), CASES)
def test_bad_input_is_a_400_with_a_message_and_an_audit_line(app, raw, needle):
    client, tmp = app
    cell = tmp / "cell.yaml"
    before = cell.read_bytes()
    lines = len((tmp / "audit.jsonl").read_text().splitlines()) \
        if (tmp / "audit.jsonl").exists() else 0
    r = client.put("/api/zones/aisle", content=raw, headers=JSON)
    assert r.status_code == 400, r.text
    error = r.json()["error"]
    assert needle in error and "\n" not in error and len(error) < 300, error
    assert cell.read_bytes() == before
    audit = [json.loads(line) for line in (tmp / "audit.jsonl").read_text().splitlines()]
    assert len(audit) == lines + 1  # exactly one line for this attempt
    assert audit[-1]["result"] == "bad_request" and audit[-1]["error"] == error
    assert audit[-1]["operator"] == OPERATOR and audit[-1]["zone"] == "aisle"
    incident = IncidentIndex(tmp / "incidents").get(r.json()["incident"])
    assert incident.record["zone_edit"]["result"] == "bad_request"


def test_a_bad_zone_id_and_a_missing_content_type_are_400s(app):
    client, tmp = app
    r = client.put("/api/zones/" + "z" * 15_000, content=_body(), headers=JSON)
    assert r.status_code == 400 and "zone id" in r.json()["error"]
    assert len(r.json()["error"]) < 300
    audit = json.loads((tmp / "audit.jsonl").read_text().splitlines()[-1])
    assert audit["zone"].endswith("(15000 characters)") and len(json.dumps(audit)) < 1500
    r = client.put("/api/zones/aisle", content=_body(), headers=basic(OPERATOR, PASSWORD))
    assert r.status_code == 400 and "content-type: application/json" in r.json()["error"]
    # a good edit still goes through the same path
    r = client.put("/api/zones/aisle", content=_body(), headers=JSON)
    assert r.status_code == 200, r.text
