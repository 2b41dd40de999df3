"""The console's incident review tools (issue 32): filters by kind, camera and review state
(a malformed one is a one-line 400), repeated alerts grouped, incidents marked reviewed by an
operator (audited, kept beside the index, never written by a forged request), an incident's
export as a zip and the list as CSV.

The data: ``console_kit.review_incidents``: a real recorder data dir (the kit's replay: a STOP
with its H.264 clip) and, written by the recorder's own store, alert incidents before it: three
mutes of cam0 within a minute, a scene change, a later mute, and a camera move whose cam1 clip
is missing."""

from __future__ import annotations

import csv
import http.client
import io
import json
import socket
import threading
import time
import zipfile

import pytest
import uvicorn
from starlette.testclient import TestClient

from monitor.console.app import build_app
from monitor.console.auth import set_password
from monitor.console.incidents import RecorderIncidents
from monitor.console.review import (
    GROUP_WINDOW_S,
    BadFilter,
    IncidentFilters,
    check_incident_id,
    group_incidents,
    parse_filters,
    to_csv,
)
from monitor.console.review_marks import FILE as MARKS_FILE
from monitor.incidents import IncidentIndex
from monitor.incidents.store import IncidentStore
from tests.console_kit import OPERATOR, PASSWORD, basic, make_console, review_incidents

# --- pure: filters ------------------------------------------------------------------------


def test_filters_parse_every_field():
    q = parse_filters([("kind", "zone_muted"), ("camera", "cam0"), ("state", "STOP"),
                       ("since", "100"), ("until", "200.5"), ("reviewed", "0"),
                       ("grouped", "1"), ("limit", "20"), ("cause", "")])
    assert q.grouped
    assert q.filters == IncidentFilters(cause=None, state="STOP", camera="cam0", since=100.0,
                                        until=200.5, limit=20, kind="zone_muted",
                                        reviewed=False)
    assert parse_filters([]).filters == IncidentFilters()


@pytest.mark.parametrize(("params", "message"), [
    pytest.param([("kind", "zone muted")], "kind 'zone muted': letters", id="space"),
    pytest.param([("kind", "x" * 10_000)], "(10000 characters)", id="10k-garbage"),
    pytest.param([("camera", "../cam0")], "camera '../cam0'", id="path"),
    pytest.param([("state", "HALT")], "state 'HALT': one of STOP, SLOW, RUN", id="state"),
    pytest.param([("since", "nan")], "since 'nan': Unix seconds", id="nan"),
    pytest.param([("since", "1e400")], "since '1e400'", id="inf"),
    pytest.param([("since", "5"), ("until", "4")], "since 5 is after until 4", id="order"),
    pytest.param([("reviewed", "maybe")], "reviewed 'maybe': 1 or 0", id="flag"),
    pytest.param([("limit", "0")], "limit '0': 1 to 500", id="limit0"),
    pytest.param([("limit", "9" * 50)], "limit '999", id="limit-huge"),
    pytest.param([("kinds", "stop")], "unknown filter 'kinds'", id="typo"),
    pytest.param([("kind", "stop"), ("kind", "latch")], "kind given twice", id="twice"),
])
def test_a_malformed_filter_is_one_line_naming_it(params, message):
    with pytest.raises(BadFilter) as caught:
        parse_filters(params)
    text = str(caught.value)
    assert message in text and "\n" not in text and len(text) < 200


def test_incident_ids_never_name_a_path():
    assert check_incident_id("20261128T114440Z-409d-0001") == "20261128T114440Z-409d-0001"
    for bad in ("../../x", "..", "a/b", ".hidden", "", "x" * 200, "a\nb"):
        with pytest.raises(BadFilter):
            check_incident_id(bad)


# --- pure: grouping -----------------------------------------------------------------------


def _row(i, started, kind="zone_muted", camera="cam0", zone="", reviewed=False):
    return {"id": f"i{i}", "started": started, "kind": kind, "camera": camera, "zone": zone,
            "reviewed": reviewed}


def test_repeated_alerts_within_the_window_are_one_group():
    rows = [_row(1, 1000), _row(2, 1000 - GROUP_WINDOW_S, reviewed=True),  # at the window
            _row(3, 1000 - 2 * GROUP_WINDOW_S - 1),  # 61 s after the group's oldest
            _row(4, 800), _row(5, 790, kind="stop,latch", zone="Z1"), _row(6, 780),
            _row(7, 770, camera="cam1"), _row(8, 760, camera="cam1")]
    groups = group_incidents(rows)
    assert [g.ids for g in groups] == [("i1", "i2"), ("i3",), ("i4",), ("i5",), ("i6",),
                                       ("i7", "i8")]  # i5 between i4 and i6 splits them
    first = groups[0]
    assert (first.count, first.first, first.last, first.reviewed) == (
        2, 1000 - GROUP_WINDOW_S, 1000, 1)
    assert first.to_dict()["title"] == "2× zone_muted cam0"
    assert groups[3].to_dict()["title"] == "1× stop,latch cam0 Z1"


def test_a_chattering_alert_is_one_group_however_long():
    rows = [_row(k, 10_000 - 50 * k) for k in range(100)]  # every 50 s for 83 minutes
    (group,) = group_incidents(rows)
    assert group.count == 100 and group.last - group.first == 50 * 99
    assert len(group_incidents(rows, window_s=49)) == 100
    assert group_incidents([]) == []


def test_csv_keeps_a_formula_as_text():
    rows = [{"id": "a", "started": 0.0, "kind": "stop", "cause": "stop", "state": "STOP",
             "camera": "cam0", "zone": "Z1", "reviewed": True,
             "review": {"operator": "anna", "at": 5.0}, "operator": None,
             "describe": "=HYPERLINK(\"http://x\")"}]
    (line,) = list(csv.DictReader(io.StringIO(to_csv(rows))))
    assert line["describe"].startswith("'=") and line["reviewed_by"] == "anna"
    assert line["started_utc"] == "1970-01-01T00:00:00Z"


# --- the console over a real data dir -----------------------------------------------------


@pytest.fixture(scope="module")
def review(tmp_path_factory):
    """(client, console, ids by name) over the kit's data dir and the alerts around it."""
    console = make_console(tmp_path_factory.mktemp("review"))
    ids = review_incidents(console.incidents.directory)
    with TestClient(build_app(console)) as client:
        yield client, console, ids


def test_a_viewer_may_not_mark_reviewed_and_the_403_names_the_level(review):
    client, console, ids = review
    set_password(console.operators.path, "vera", "vera-password-1", "viewer")
    marks = console.incidents.directory / MARKS_FILE
    before = marks.read_bytes() if marks.exists() else None
    r = client.post(f"/api/incidents/{ids['scene']}/reviewed",
                    headers=basic("vera", "vera-password-1"))
    assert r.status_code == 403, r.text
    assert r.json()["error"] == ("viewer 'vera' may not mark an incident reviewed: it needs "
                                 "the operator or admin level")
    assert (marks.read_bytes() if marks.exists() else None) == before
    assert ids["scene"] not in [row["id"] for row in
                                client.get("/api/incidents?reviewed=1").json()["incidents"]]
    last = json.loads(console.audit.path.read_text().splitlines()[-1])
    assert (last["result"], last["operator"], last["level"]) == ("forbidden", "vera", "viewer")


def test_the_list_filters_by_kind_and_camera_and_offers_them(review):
    client, _, ids = review
    body = client.get("/api/incidents?kind=zone_muted").json()
    assert [r["id"] for r in body["incidents"]] == [ids["mute4"], ids["mute3"], ids["mute2"],
                                                    ids["mute1"]]
    assert all(r["kind"] == "zone_muted" and r["cause"] == "alert(zone_muted)"
               for r in body["incidents"])
    cam1 = client.get("/api/incidents?camera=cam1").json()["incidents"]
    assert [r["id"] for r in cam1] == [ids["moved"]]
    stops = client.get("/api/incidents?kind=stop&camera=cam0").json()["incidents"]
    assert [(r["id"], r["zone"]) for r in stops] == [
        (ids["stop"], "cam0-protective,robot-protective")]
    assert client.get("/api/incidents?kind=alert").json()["incidents"][-1]["id"] == ids["moved"]
    facets = client.get("/api/incidents/facets").json()
    assert facets == {"kinds": ["alert", "camera_moved", "latch", "scene_change", "stop",
                                "zone_muted"], "cameras": ["cam0", "cam1"]}


def test_a_malformed_filter_is_a_400_with_one_line(review):
    client = review[0]
    for url in ("/api/incidents?kind=" + "%00garbage" * 1024, "/api/incidents?state=HALT",
                "/api/incidents?kindd=stop", "/api/incidents.csv?since=soon"):
        r = client.get(url)
        assert r.status_code == 400, url
        error = r.json()["error"]
        assert "\n" not in error and len(error) < 200, error
    assert "(10240 characters)" in client.get(
        "/api/incidents?kind=" + "x" * 10240).json()["error"]


def test_repeated_mutes_are_one_group_and_a_different_incident_splits_them(review):
    client, _, ids = review
    body = client.get("/api/incidents?grouped=1").json()
    assert [g["ids"] for g in body["groups"]] == [
        [ids["stop"]], [ids["mute4"]], [ids["scene"]],
        [ids["mute3"], ids["mute2"], ids["mute1"]], [ids["moved"]]]
    three = body["groups"][3]
    assert three["title"] == "3× zone_muted cam0" and three["count"] == 3
    assert three["last"] - three["first"] == pytest.approx(40.0)
    assert "groups" not in client.get("/api/incidents").json()


def test_marking_reviewed_needs_a_credential_and_is_kept_beside_the_index(review):
    client, console, ids = review
    marks = console.incidents.directory / MARKS_FILE
    audit = console.audit.path
    lines_before = audit.read_text().splitlines() if audit.exists() else []
    # forged: no credential, a wrong password, a malformed header: nothing marked
    for headers in ({}, basic(OPERATOR, "wrong password"),
                    {"authorization": "Basic !!notbase64"}):
        r = client.post(f"/api/incidents/{ids['mute1']}/reviewed", headers=headers)
        assert r.status_code == 401 and "not accepted" in r.json()["error"]
    assert not marks.exists()
    refused = [json.loads(line) for line in audit.read_text().splitlines()[len(lines_before):]]
    assert [(a["event"], a["result"], a["incident"]) for a in refused] == [
        ("incident_reviewed", "refused", ids["mute1"])] * 3
    assert client.get("/api/incidents?reviewed=1").json()["incidents"] == []

    r = client.post(f"/api/incidents/{ids['mute1']}/reviewed",
                    headers=basic(OPERATOR, PASSWORD))
    assert r.status_code == 200, r.text
    assert r.json()["review"]["operator"] == OPERATOR
    last = json.loads(audit.read_text().splitlines()[-1])
    assert (last["event"], last["result"], last["operator"], last["incident"]) == (
        "incident_reviewed", "reviewed", OPERATOR, ids["mute1"])
    # an unknown or malformed id: refused, audited, nothing marked
    assert client.post("/api/incidents/nothing-here/reviewed",
                       headers=basic(OPERATOR, PASSWORD)).status_code == 404
    assert client.post("/api/incidents/..%2e/reviewed",
                       headers=basic(OPERATOR, PASSWORD)).status_code in (400, 404)

    # the list shows it, filters on it, and a console started anew over the same dir too
    reviewed = client.get("/api/incidents?reviewed=1").json()["incidents"]
    assert [(r["id"], r["review"]["operator"]) for r in reviewed] == [(ids["mute1"], OPERATOR)]
    assert ids["mute1"] not in {r["id"] for r in
                                client.get("/api/incidents?reviewed=0").json()["incidents"]}
    again = RecorderIncidents(console.incidents.directory)
    (row,) = again.list(IncidentFilters(reviewed=True))
    assert row["id"] == ids["mute1"] and row["reviewed"]
    grouped = client.get("/api/incidents?grouped=1").json()["groups"]
    assert next(g for g in grouped if ids["mute1"] in g["ids"])["reviewed"] == 1
    # the recorder's index is untouched by the mark
    assert "reviewed" not in json.dumps(IncidentIndex(console.incidents.directory)
                                        .get(ids["mute1"]).record)


def test_an_export_is_a_zip_of_the_record_clips_and_thumbnails(review):
    client, _, ids = review
    r = client.get(f"/api/incidents/{ids['stop']}/export")
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
    assert r.headers["content-disposition"] == \
        f'attachment; filename="incident-{ids["stop"]}.zip"'
    z = zipfile.ZipFile(io.BytesIO(r.content))
    assert sorted(z.namelist()) == ["cam0.mp4", "export.json", "incident.json",
                                    "thumb-cam0.jpg"]
    assert json.loads(z.read("incident.json"))["id"] == ids["stop"]
    clip = IncidentIndex(review[1].incidents.directory).get(ids["stop"]).clip_paths()["cam0"]
    assert z.read("cam0.mp4") == clip.read_bytes()
    assert z.read("thumb-cam0.jpg")[:2] == b"\xff\xd8"
    assert json.loads(z.read("export.json"))["missing"] == []


def test_an_export_with_a_missing_clip_says_which(review):
    client, _, ids = review
    r = client.get(f"/api/incidents/{ids['moved']}/export")
    assert r.status_code == 200
    assert r.headers["x-incident-missing"] == "cam1.mp4: not found in the incident's folder"
    z = zipfile.ZipFile(io.BytesIO(r.content))
    assert "cam0.mp4" in z.namelist() and "cam1.mp4" not in z.namelist()
    assert json.loads(z.read("export.json"))["missing"] == [
        {"file": "cam1.mp4", "why": "not found in the incident's folder"}]


def test_an_export_never_leaves_the_data_directory(review, tmp_path):
    client, console, ids = review
    directory = console.incidents.directory
    # a record naming a file outside: the file is not exported, the export says why
    secret = directory.parent / "secret.mp4"
    secret.write_bytes(b"not yours")
    store = IncidentStore(directory)
    try:
        base = IncidentIndex(directory).get(ids["scene"]).record
        (directory / "forged").mkdir()
        store.put({**base, "id": "forged", "wall": base["wall"] - 900,
                   "clips": {"cam0": {"file": "../../secret.mp4"}}}, complete=True)
    finally:
        store.close()
    r = client.get("/api/incidents/forged/export")
    z = zipfile.ZipFile(io.BytesIO(r.content))
    assert b"not yours" not in r.content and "secret.mp4" not in z.namelist()
    assert json.loads(z.read("export.json"))["missing"] == [
        {"file": "../../secret.mp4", "why": "outside the data directory: not exported"}]
    # ids that are paths: never a file (Starlette's router or the id check refuse them)
    assert client.get("/api/incidents/..%2F..%2Fx/export").status_code in (400, 404)
    assert client.get("/api/incidents/..%2e/export").status_code == 400
    assert client.get("/api/incidents/nothing/export").status_code == 404


def test_raw_path_ids_over_a_socket_are_refused(review):
    """Through a real HTTP server: the request line as an attacker writes it (no client
    normalising ``..``)."""
    console = review[1]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(build_app(console), host="127.0.0.1", port=port,
                                           log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 30
        while not server.started:
            assert time.monotonic() < deadline, "the console did not start within 30 s"
            time.sleep(0.05)
        for path in ("/api/incidents/../../x/export", "/api/incidents/%2e%2e/export",
                     "/api/incidents/..%2F..%2Fetc%2Fpasswd/export"):
            con = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
            con.putrequest("GET", path, skip_host=False)
            con.endheaders()
            resp = con.getresponse()
            body = resp.read()
            assert resp.status in (400, 404), (path, resp.status)
            assert b"root:" not in body and resp.getheader("content-type") != "application/zip"
            con.close()
    finally:
        server.should_exit = True
        thread.join(timeout=10)


def test_the_filtered_list_as_csv(review):
    client, _, ids = review
    r = client.get("/api/incidents.csv?kind=zone_muted")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    assert r.headers["content-disposition"] == 'attachment; filename="incidents.csv"'
    rows = list(csv.DictReader(io.StringIO(r.text)))
    assert [row["id"] for row in rows] == [ids["mute4"], ids["mute3"], ids["mute2"],
                                           ids["mute1"]]
    assert {row["kind"] for row in rows} == {"zone_muted"}
