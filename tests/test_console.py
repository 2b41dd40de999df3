"""The console without a browser: credentials, where it may listen, the incident source and
the zone editor's rules (Starlette's test client against the real app and zone files)."""

from __future__ import annotations

import base64

import pytest
from starlette.testclient import TestClient

from monitor.console.app import Console, build_app
from monitor.console.audit import AuditLog
from monitor.console.auth import (
    Operators,
    read_passwords,
    require_safe_listen,
)
from monitor.console.edits import BUSY_S, ZoneEditIncidents
from monitor.console.incidents import IncidentFilters, RecorderIncidents
from monitor.console.live import LiveRenderer, LiveState
from monitor.console.zones_api import ZoneEditor
from monitor.errors import ConfigError
from monitor.zones import load_cell
from tests.console_kit import (
    OPERATOR,
    PASSWORD,
    incident_dir,
    passwords,
    zone_file,
)
from tests.helpers import assert_one_line, assert_one_line_error, run_monitor

SQUARE = [[900, 150], [1200, 150], [1200, 400], [900, 400]]
BOWTIE = [[900, 150], [1200, 400], [1200, 150], [900, 400]]


def _client(tmp_path, with_passwords: bool = True):
    cell = zone_file(tmp_path)
    editor = ZoneEditor(cell)
    live = LiveState()
    incidents = incident_dir(tmp_path)
    console = Console("c", live, LiveRenderer(live, editor.cell, {}), editor,
                      RecorderIncidents(incidents),
                      Operators(passwords(tmp_path) if with_passwords else None),
                      AuditLog(tmp_path / "audit.jsonl"), {},
                      edits=ZoneEditIncidents(incidents, "c"))
    return TestClient(build_app(console)), cell


def _auth(name: str, password: str) -> dict:
    return {"authorization": "Basic " + base64.b64encode(f"{name}:{password}".encode()).decode()}


def _audit(tmp_path) -> list[str]:
    import json

    return [json.loads(line)["result"] for line in
            (tmp_path / "audit.jsonl").read_text().splitlines()]


def test_an_edit_without_a_valid_credential_is_refused_audited_and_writes_nothing(tmp_path):
    client, cell = _client(tmp_path)
    before = cell.read_bytes()
    body = {"camera": "cam0", "kind": "protective", "points_px": SQUARE}
    assert client.put("/api/zones/aisle", json=body).status_code == 401
    assert client.put("/api/zones/aisle", json=body,
                      headers=_auth(OPERATOR, "wrong password")).status_code == 401
    assert client.put("/api/zones/aisle", json=body,
                      headers=_auth("mallory", PASSWORD)).status_code == 401
    assert cell.read_bytes() == before and not cell.with_name("cell.yaml.bak").exists()
    assert _audit(tmp_path) == ["refused"] * 3
    # reading needs no login
    assert client.get("/api/zones").status_code == 200
    assert client.get("/api/state").json()["state"] == "STOP"  # nothing heard: STOP
    ok = client.put("/api/zones/aisle", json=body, headers=_auth(OPERATOR, PASSWORD))
    assert ok.status_code == 200, ok.text
    assert load_cell(cell).zone("aisle").kind == "protective"
    assert _audit(tmp_path)[-1] == "saved"


def test_without_a_passwords_file_the_console_is_read_only(tmp_path):
    client, cell = _client(tmp_path, with_passwords=False)
    before = cell.read_bytes()
    r = client.put("/api/zones/aisle", json={"camera": "cam0", "kind": "protective",
                                             "points_px": SQUARE},
                   headers=_auth(OPERATOR, PASSWORD))
    assert r.status_code == 403 and "without --passwords" in r.json()["error"]
    assert cell.read_bytes() == before


def test_invalid_polygons_are_refused_with_monitor_zones_messages(tmp_path):
    client, cell = _client(tmp_path)
    before = cell.read_bytes()
    cases = [
        ({"camera": "cam0", "kind": "protective", "points_px": BOWTIE},
         "self-intersecting polygon"),
        ({"camera": "cam0", "kind": "protective", "points_px": [[0, 0], [2000, 0], [0, 50]]},
         "outside the 1280x720 image"),
        ({"camera": "cam9", "kind": "protective", "points_px": SQUARE}, "unknown camera"),
        ({"camera": "cam0", "kind": "protective", "points_px": [[1, "x"]]}, "[x, y]"),
        ({"camera": "cam0", "kind": "teleport", "points_px": SQUARE}, "kind 'teleport'"),
    ]
    for body, needle in cases:
        r = client.put("/api/zones/aisle", json=body, headers=_auth(OPERATOR, PASSWORD))
        assert r.status_code == 422 and needle in r.json()["error"], (needle, r.text)
        assert "\n" not in r.json()["error"]
    # moving an existing polygon into a bow tie is refused the same way
    r = client.put("/api/zones/cam0-protective", json={"points_px": BOWTIE},
                   headers=_auth(OPERATOR, PASSWORD))
    assert r.status_code == 422 and "self-intersecting" in r.json()["error"]
    # a volume is not edited as a polygon
    r = client.put("/api/zones/robot-protective", json={"points_px": SQUARE},
                   headers=_auth(OPERATOR, PASSWORD))
    assert r.status_code == 422 and "monitor zones edit" in r.json()["error"]
    assert cell.read_bytes() == before
    assert set(_audit(tmp_path)) == {"invalid"}


def test_a_move_keeps_comments_and_refuses_a_stale_page(tmp_path):
    client, cell = _client(tmp_path)
    sha = client.get("/api/zones").json()["sha"]
    moved = [[480.0, 535.0], [800.0, 535.0], [757.1, 403.5], [522.9, 403.5]]  # grown: no draft
    r = client.put("/api/zones/cam0-protective", json={"points_px": moved, "base": sha},
                   headers=_auth(OPERATOR, PASSWORD))
    assert r.status_code == 200, r.text
    text = cell.read_text()
    assert "# The floor squares of the two volumes above" in text  # comments kept
    assert load_cell(cell).zone("cam0-protective").points_px[0] == (480.0, 535.0)
    # the same page saves again on the old version: refused, not silently undone
    r = client.put("/api/zones/cam0-protective", json={"points_px": moved, "base": sha},
                   headers=_auth(OPERATOR, PASSWORD))
    assert r.status_code == 422 and "changed since this page loaded" in r.json()["error"]


def test_off_loopback_needs_tls_and_passwords():
    for host in ("127.0.0.1", "::1", "localhost"):
        require_safe_listen(host, tls=False, operators=False)
    for host, tls, ops, needle in (("0.0.0.0", False, True, "--https-cert and --https-key"),
                                   ("10.0.0.5", True, False, "operator passwords"),
                                   ("192.168.1.2", False, False, "TLS")):
        with pytest.raises(ConfigError) as exc:
            require_safe_listen(host, tls=tls, operators=ops)
        assert_one_line(exc.value, needle)
    require_safe_listen("10.0.0.5", tls=True, operators=True)


def test_the_console_refuses_to_start_on_a_network_address_without_tls(tmp_path):
    cell = zone_file(tmp_path)
    proc = run_monitor("console", "--zones", cell, "--unauthenticated",
                       "--listen", "0.0.0.0:18099", timeout=60)
    assert proc.returncode == 2
    assert_one_line_error(proc, "not loopback", "TLS (--https-cert and --https-key)",
                          "operator passwords")
    assert "--tls-" not in proc.stderr  # the Zenoh link's options, not the console's
    proc = run_monitor("console", "--zones", cell, "--unauthenticated", "--passwords",
                       passwords(tmp_path), "--listen", "10.1.2.3:18099", timeout=60)
    assert proc.returncode == 2
    assert_one_line_error(proc, "TLS")


def test_console_passwd_writes_a_private_scrypt_line(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "pw"
    proc = subprocess.run([sys.executable, "-m", "monitor", "console", "passwd", str(path),
                           "bob"], input="a long secret\n", capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert path.stat().st_mode & 0o777 == 0o600
    stored = read_passwords(path)["bob"]
    assert stored.startswith("scrypt$") and "a long secret" not in path.read_text()
    assert Operators(path).check(_auth("bob", "a long secret")["authorization"]) == "bob"
    assert Operators(path).check(_auth("bob", "a long secreT")["authorization"]) is None
    short = subprocess.run([sys.executable, "-m", "monitor", "console", "passwd", str(path),
                            "eve"], input="short\n", capture_output=True, text=True,
                           timeout=60)
    assert short.returncode == 2 and "too short" in short.stderr


def _forge(d, source_id: str, new_id: str, **changes) -> None:
    """Another row in the real index, written by the recorder's own store."""
    from monitor.incidents import IncidentIndex
    from monitor.incidents.store import IncidentStore

    record = {**IncidentIndex(d).get(source_id).record, "id": new_id, **changes}
    store = IncidentStore(d)
    try:
        store.put(record, complete=True)
    finally:
        store.close()


def test_incident_source_filters_and_never_serves_outside_its_directory(tmp_path):
    from monitor.incidents import IncidentIndex

    d = incident_dir(tmp_path)
    (real,) = IncidentIndex(d).list()  # the replay's entry: stop, latch, a cam0 clip
    assert real.causes == ("stop", "latch") and real.clip_paths()
    (tmp_path / "secret.txt").write_text("not a clip")
    (d / "evil").mkdir()
    (d / "evil" / "cam0.mp4").symlink_to(tmp_path / "secret.txt")
    _forge(d, real.id, "evil", wall=real.wall - 60,
           clips={"cam0": {"file": "../../secret.txt"}, "cam1": {"file": "cam0.mp4"}})
    _forge(d, real.id, "alert-1", wall=real.wall + 30, causes=["alert"], state="RUN",
           clips={})
    src = RecorderIncidents(d)
    assert [i["id"] for i in src.list(IncidentFilters())] == ["alert-1", real.id, "evil"]
    assert [i["id"] for i in src.list(IncidentFilters(camera="cam0", cause="stop",
                                                      state="STOP"))] == [real.id, "evil"]
    assert [i["id"] for i in src.list(IncidentFilters(state="RUN"))] == ["alert-1"]
    assert [i["id"] for i in src.list(IncidentFilters(since=real.wall - 1,
                                                      until=real.wall + 1))] == [real.id]
    assert [i["id"] for i in src.list(IncidentFilters(limit=1))] == ["alert-1"]
    row = src.list(IncidentFilters(cause="latch"))[0]
    assert row["has_clip"] and row["cause"] == "stop,latch" and row["camera"] == "cam0"
    assert src.clip_path(real.id).name == "cam0.mp4"
    # a forged record naming a file outside the data dir, or a symlink out of it: no clip
    assert src.clip_path("evil") is None and src.clip_path("evil", "cam1") is None
    assert not src.list(IncidentFilters(state="STOP"))[1]["has_clip"]
    assert src.clip_path("alert-1") is None and src.clip_path("nothing") is None
    assert RecorderIncidents(tmp_path / "nowhere").list(IncidentFilters()) == []
    (tmp_path / "app").mkdir()
    client, _ = _client(tmp_path / "app")
    listed = client.get("/api/incidents").json()["incidents"]
    assert listed and listed[0]["has_clip"]
    assert client.get("/api/incidents/evil/clip").status_code == 404
    r = client.get(f"/api/incidents/{listed[0]['id']}/clip", headers={"range": "bytes=0-99"})
    assert r.status_code == 206 and len(r.content) == 100  # seeking in the player
    assert r.headers["content-type"] == "video/mp4"


def test_every_zone_edit_is_an_incident_of_the_recorder_and_a_locked_index_only_audits(
        tmp_path):
    import json
    import sqlite3
    import time

    from monitor.incidents import IncidentIndex

    client, cell = _client(tmp_path)
    d = tmp_path / "incidents"
    before = load_cell(cell).config_hash
    body = {"camera": "cam0", "kind": "protective", "points_px": SQUARE}
    assert client.put("/api/zones/aisle", json=body,
                      headers=_auth("mallory", PASSWORD)).status_code == 401
    r = client.put("/api/zones/aisle", json={**body, "points_px": BOWTIE},
                   headers=_auth(OPERATOR, PASSWORD))
    assert r.status_code == 422 and r.json()["incident"]
    ok = client.put("/api/zones/aisle", json=body, headers=_auth(OPERATOR, PASSWORD))
    assert ok.status_code == 200 and ok.json()["incident"]
    after = load_cell(cell).config_hash
    edits = list(reversed(IncidentIndex(d).list(cause="zone_edit")))
    # the refused credential is audited only (tests/test_console_refusals.py)
    assert [(e.operator, e.record["zone_edit"]["result"], e.record["zone_edit"]["accepted"])
            for e in edits] == [(OPERATOR, "invalid", False), (OPERATOR, "saved", True)]
    assert "self-intersecting polygon" in edits[0].record["zone_edit"]["message"]
    assert (edits[1].record["zone_edit"]["old_hash"],
            edits[1].record["zone_edit"]["new_hash"]) == (before, after)
    assert edits[1].id == ok.json()["incident"] and not any(e.clip_paths() for e in edits)
    assert all(e.complete and e.causes == ("zone_edit",) for e in edits)
    # the console lists them beside the recorder's own incidents
    listed = client.get("/api/incidents?cause=zone_edit").json()["incidents"]
    assert len(listed) == 2 and not any(i["has_clip"] for i in listed)
    # another process holds the index's write lock past the console's busy timeout: the edit
    # is still saved and audited, the audit says the incident could not be written
    lock = sqlite3.connect(str(d / "index.sqlite3"), isolation_level=None)
    lock.execute("BEGIN EXCLUSIVE")
    try:
        started = time.monotonic()
        r = client.put("/api/zones/aisle", json={**body, "points_px": [[900, 140], *SQUARE[1:]]},
                       headers=_auth(OPERATOR, PASSWORD))
        waited = time.monotonic() - started
    finally:
        lock.execute("ROLLBACK")
        lock.close()
    assert r.status_code == 200 and r.json()["incident"] is None
    assert waited >= BUSY_S * 0.9  # SQLite's lock serialised the writers: it waited, then gave up
    audit = [json.loads(line) for line in (tmp_path / "audit.jsonl").read_text().splitlines()]
    assert audit[-2]["result"] == "saved"
    assert audit[-1]["event"] == "zone_edit_incident_error" and "locked" in \
        audit[-1]["incident_error"]
    # the lock gone, the next edit is recorded again (grown once more: no draft)
    r = client.put("/api/zones/aisle", json={**body, "points_px": [[900, 130], *SQUARE[1:]]},
                   headers=_auth(OPERATOR, PASSWORD))
    assert r.status_code == 200 and r.json()["incident"]


def test_live_image_and_state_need_no_login(tmp_path):
    client, _ = _client(tmp_path)
    r = client.get("/api/live/cam0.jpg")
    assert r.status_code == 200 and r.content[:2] == b"\xff\xd8"
    assert client.get("/api/live/nope.jpg").status_code == 404
    assert client.get("/").status_code == 200 and "console.js" in client.get("/").text
