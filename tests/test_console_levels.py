"""Issue 32, part 1: user levels of the console (viewer, operator, admin). The table of who may
do what (pure); the passwords file with levels, the format before levels and forged levels; the
real app (Starlette's test client over the real zone file, the real scrypt passwords file, the
real audit log): a viewer's edit is a 403 naming the level needed and is audited; viewing with
a login off loopback; who may reset is the monitor's operators file, read-only."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from starlette.testclient import TestClient

from monitor.console.app import build_app
from monitor.console.auth import Operators, hash_password, read_entries, set_password
from monitor.console.levels import ACTIONS, LEVELS, NEVER, may, parse_level, refusal, table
from monitor.console.sessions import COOKIE, Sessions
from monitor.errors import ConfigError
from monitor.wire.signing import key_fingerprint, public_key_text
from monitor.zones import load_cell
from monitor.zones.files import draft_path
from tests.console_kit import audit_lines, basic, plain_console, zone_file

SQUARE = [[900, 150], [1200, 150], [1200, 400], [900, 400]]
POLYGON = {"camera": "cam0", "kind": "protective", "points_px": SQUARE}
MUTE = {"operators": ["anna"], "max_s": 60}
USERS = {"vera": "viewer", "otto": "operator", "ada": "admin"}
PASSWORD = "a long console password"
LEGACY = "olga"  # a line in the format before levels: name:scrypt$...


# --- the table (pure) ---------------------------------------------------------------------

RIGHTS = [  # (level, action, allowed): every pair, written out
    ("viewer", "view", True), ("viewer", "edit_zone", False), ("viewer", "edit_mute", False),
    ("viewer", "edit_sets", False), ("viewer", "edit_volume", False),
    ("viewer", "mark_reviewed", False), ("operator", "mark_reviewed", True),
    ("admin", "mark_reviewed", True),
    ("viewer", "confirm_clear", False), ("operator", "confirm_clear", True),
    ("admin", "confirm_clear", True),
    # a plain reset from the live page, signed with the operator's own reset key
    ("viewer", "reset", False), ("operator", "reset", True), ("admin", "reset", True),
    ("operator", "view", True), ("operator", "edit_zone", True),
    ("operator", "edit_mute", False), ("operator", "edit_sets", False),
    ("operator", "edit_volume", False),
    ("admin", "view", True), ("admin", "edit_zone", True), ("admin", "edit_mute", True),
    ("admin", "edit_sets", True), ("admin", "edit_volume", True),
]


@pytest.mark.parametrize(("level", "action", "allowed"),
                         [pytest.param(*r, id=f"{r[0]}-{r[1]}") for r in RIGHTS])
def test_may_level_do_action(level, action, allowed):
    assert may(level, action) is allowed
    assert (refusal("x", level, action) is None) is allowed


def test_the_table_covers_every_pair_and_nothing_grants_a_reset():
    """The level alone grants no reset: the console's reset and confirm-clear are signed with
    the operator's own key of the operators file (tests/test_console_confirm_clear.py)."""
    assert {(lv, a) for lv, a, _ in RIGHTS} == {(lv, a) for lv in LEVELS for a in ACTIONS}
    for action in NEVER:  # apply, mute, select a set: no level of the console
        assert not any(may(level, action) for level in LEVELS)
        assert "operators file" in refusal("ada", "admin", action)
    for bad in (None, "root", "", "Admin", "admin "):
        assert not may(bad, "view")
    assert not may("admin", "format_disk")  # unknown actions: never
    assert [r["levels"] for r in table() if r["action"] == "reset"] == [["operator", "admin"]]
    assert set(NEVER) == {"apply", "mute", "select_set"}


def test_a_refusal_names_the_level_needed_in_one_line():
    assert refusal("vera", "viewer", "edit_zone") == (
        "viewer 'vera' may not edit zone polygons: it needs the operator or admin level")
    assert refusal("otto", "operator", "edit_mute") == (
        "operator 'otto' may not change a zone's mute setting: it needs the admin level")
    assert parse_level("administrator") == "admin"
    with pytest.raises(ValueError, match="level 'root': one of viewer, operator, admin"):
        parse_level("root")


# --- the passwords file -------------------------------------------------------------------

@pytest.fixture(scope="module")
def hashes() -> dict[str, str]:
    """One scrypt hash per user, made once (scrypt is slow on purpose)."""
    return {name: hash_password(PASSWORD) for name in (*USERS, LEGACY)}


def _write_passwords(path, hashes, extra: str = "") -> None:
    lines = [f"{name}:{level}:{hashes[name]}" for name, level in USERS.items()]
    lines.append(f"{LEGACY}:{hashes[LEGACY]}")  # the format before levels
    path.write_text("# console users\n" + "\n".join(lines) + "\n" + extra)
    os.chmod(path, 0o600)


def test_a_line_without_a_level_is_an_operator_and_a_forged_level_stops_the_start(
        tmp_path, hashes):
    path = tmp_path / "pw"
    _write_passwords(path, hashes)
    entries = read_entries(path)
    assert {n: e.level for n, e in entries.items()} == {**USERS, LEGACY: "operator"}
    for forged, message in [
        (f"eve:root:{hashes['ada']}", "pw:6: level 'root': one of viewer, operator, admin"),
        (f"eve:admin :{hashes['ada']}", "pw:6: level 'admin ': one of"),
        (f"eve:{'x' * 5000}:{hashes['ada']}", "pw:6: level 'xxxxxxxxxxxxxxxxxxxx... (5000 "
                                               "characters)'"),
        ("eve:admin:plaintext", "pw:6: not a 'name:level:scrypt$...' line"),
        ("eve:admin", "pw:6: not a 'name:level:scrypt$...' line"),
        (f"ada:viewer:{hashes['vera']}", "pw:6: 'ada' is listed twice"),
    ]:
        _write_passwords(path, hashes, forged + "\n")
        with pytest.raises(ConfigError) as err:
            Operators(path)
        assert message in str(err.value) and "\n" not in str(err.value)


def test_set_password_keeps_a_level_and_writes_every_line_with_one(tmp_path, hashes):
    path = tmp_path / "pw"
    _write_passwords(path, hashes)
    assert set_password(path, "vera", PASSWORD) == "viewer"  # kept
    assert set_password(path, "nina", PASSWORD) == "operator"  # a new user's default
    assert set_password(path, "otto", PASSWORD, "admin") == "admin"
    with pytest.raises(ConfigError, match="level 'god'"):
        set_password(path, "otto", PASSWORD, "god")
    text = path.read_text()
    assert f"{LEGACY}:operator:scrypt$" in text  # rewritten with its level, same rights
    assert {n: e.level for n, e in read_entries(path).items()} == {
        "vera": "viewer", "otto": "admin", "ada": "admin", LEGACY: "operator",
        "nina": "operator"}
    assert path.stat().st_mode & 0o777 == 0o600


def test_console_passwd_level_option(tmp_path):
    path = tmp_path / "pw"
    proc = subprocess.run([sys.executable, "-m", "monitor", "console", "passwd", str(path),
                           "ada", "--level", "admin"], input=PASSWORD + "\n",
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "password of ada (admin) set" in proc.stdout
    assert read_entries(path)["ada"].level == "admin"
    bad = subprocess.run([sys.executable, "-m", "monitor", "console", "passwd", str(path),
                          "eve", "--level", "root"], input=PASSWORD + "\n",
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "invalid choice: 'root'" in bad.stderr
    assert "eve" not in path.read_text()


# --- the real app ---------------------------------------------------------------------------

@pytest.fixture
def cell_dir(tmp_path, hashes):
    zone_file(tmp_path)
    _write_passwords(tmp_path / "pw", hashes)
    return tmp_path


def test_each_level_edits_what_it_may_and_a_refusal_is_a_403_naming_the_level(cell_dir):
    client = TestClient(build_app(plain_console(cell_dir)))
    cell = cell_dir / "cell.yaml"
    before = cell.read_bytes()
    r = client.put("/api/zones/aisle", json=POLYGON, headers=basic("vera", PASSWORD))
    assert r.status_code == 403
    assert r.json() == {"error": "viewer 'vera' may not edit zone polygons: it needs the "
                                 "operator or admin level"}
    r = client.put("/api/setup/mute/robot-protective", json=MUTE,
                   headers=basic("otto", PASSWORD))
    assert r.status_code == 403 and r.json()["error"].endswith("it needs the admin level")
    r = client.put("/api/setup/rules", json={"switch_over_s": 2},
                   headers=basic("vera", PASSWORD))
    assert r.status_code == 403
    assert cell.read_bytes() == before
    forbidden = [e for e in audit_lines(cell_dir) if e["result"] == "forbidden"]
    assert [(e["operator"], e["level"], e["edit"]) for e in forbidden] == [
        ("vera", "viewer", "edit_zone"), ("otto", "operator", "edit_mute"),
        ("vera", "viewer", "edit_sets")]
    assert all(PASSWORD not in json.dumps(e) for e in audit_lines(cell_dir))
    # an operator edits a polygon as before levels; so does the line without a level
    assert client.put("/api/zones/aisle", json=POLYGON,
                      headers=basic("otto", PASSWORD)).status_code == 200
    assert client.put("/api/zones/aisle2", json=POLYGON,
                      headers=basic(LEGACY, PASSWORD)).status_code == 200
    r = client.put("/api/setup/mute/robot-protective", json=MUTE,
                   headers=basic(LEGACY, PASSWORD))
    assert r.status_code == 403  # but not the setup
    r = client.put("/api/setup/mute/robot-protective", json=MUTE,
                   headers=basic("ada", PASSWORD))
    # a protective zone made mutable weakens protection: a draft for a signed apply (issue 48)
    assert r.status_code == 202, r.text
    assert load_cell(cell).zone("robot-protective").mute is None
    assert load_cell(draft_path(cell)).zone("robot-protective").mute.max_s == 60
    assert [e["result"] for e in audit_lines(cell_dir)][-3:] == ["saved", "forbidden", "draft"]
    # a wrong password is a 401 (whoever reaches the port), not a 403
    assert client.put("/api/zones/aisle", json=POLYGON,
                      headers=basic("ada", "wrong password")).status_code == 401


def test_a_level_forged_into_the_file_while_running_lets_nobody_in(cell_dir, hashes):
    client = TestClient(build_app(plain_console(cell_dir)))
    pw = cell_dir / "pw"
    _write_passwords(pw, hashes, f"eve:superuser:{hashes['ada']}\n")
    st = pw.stat()
    os.utime(pw, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # a new mtime: re-read
    cell = cell_dir / "cell.yaml"
    before = cell.read_bytes()
    for name in ("ada", "eve"):
        r = client.put("/api/setup/mute/robot-protective", json=MUTE,
                       headers=basic(name, PASSWORD))
        assert r.status_code == 401, r.text
    assert cell.read_bytes() == before
    # a level changed in the file takes effect at once: ada demoted to viewer
    shutil.copy(pw, cell_dir / "pw.bak")
    pw.write_text(f"ada:viewer:{hashes['ada']}\n")
    os.utime(pw, ns=(st.st_atime_ns, st.st_mtime_ns + 2 * 10**9))
    r = client.put("/api/zones/aisle", json=POLYGON, headers=basic("ada", PASSWORD))
    assert r.status_code == 403 and "viewer 'ada'" in r.json()["error"]


def test_viewing_off_loopback_needs_a_login_and_a_removed_user_is_refused_at_once(
        cell_dir, hashes):
    client = TestClient(build_app(plain_console(cell_dir, view_login=True)))
    r = client.get("/api/state")
    assert r.status_code == 401 and "needs a login" in r.json()["error"]
    for url in ("/api/zones", "/api/incidents", "/api/setup", "/api/access",
                "/api/zones/cam0/image.jpg", "/api/live/cam0.jpg"):
        assert client.get(url).status_code == 401, url
    assert client.get("/setup").status_code == 200  # pages hold no data
    assert client.get("/static/setup.js").status_code == 200
    assert client.get("/api/me").json()["name"] is None
    r = client.post("/api/login", headers=basic("vera", "wrong password"))
    assert r.status_code == 401 and COOKIE not in r.cookies
    r = client.post("/api/login", headers=basic("vera", PASSWORD))
    assert r.status_code == 200 and r.json() == {"name": "vera", "level": "viewer"}
    cookie = r.headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie
    assert client.get("/api/state").status_code == 200
    me = client.get("/api/me").json()
    assert me["level"] == "viewer" and me["may"]["view"] and not me["may"]["edit_zone"]
    # the session is no credential for an edit: each edit sends its own password
    assert client.put("/api/zones/aisle", json=POLYGON).status_code == 401
    # vera removed from the file: refused at the next request
    pw = cell_dir / "pw"
    st = pw.stat()
    pw.write_text(f"ada:admin:{hashes['ada']}\n")
    os.utime(pw, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    r = client.get("/api/state")
    assert r.status_code == 401 and "'vera' is no longer a user" in r.json()["error"]
    assert client.post("/api/login", headers=basic("ada", PASSWORD)).status_code == 200
    assert client.get("/api/state").status_code == 200
    client.post("/api/logout")
    assert client.get("/api/state").status_code == 401
    logins = [e["operator"] for e in audit_lines(cell_dir) if e["event"] == "login"]
    assert logins == ["vera", "ada"]


def test_on_loopback_viewing_stays_open():
    sessions = Sessions(clock=lambda: 0.0, max_per_user=2)
    tokens = [sessions.open(n) for n in ("a", "a", "a")]
    assert sessions.name(tokens[0]) is None and sessions.name(tokens[2]) == "a"  # bounded
    later = Sessions(clock=iter([0.0, 9.0e9]).__next__)
    assert later.name(later.open("a")) is None  # expired
    assert sessions.name("x" * 5000) is None


def test_who_may_reset_is_the_operators_file_shown_read_only(cell_dir):
    keys = {name: public_key_text(Ed25519PrivateKey.generate().public_key())
            for name in ("anna", "bert")}
    ops = cell_dir / "operators"
    ops.write_text("# who may reset\n" + "".join(f"{n} {k}\n" for n, k in keys.items()))
    os.chmod(ops, 0o644)
    client = TestClient(build_app(plain_console(cell_dir, reset_operators=ops)))
    body = client.get("/api/access").json()
    assert body["reset"] == {"file": str(ops), "error": None, "operators": [
        {"name": n, "fingerprint": key_fingerprint(k)} for n, k in sorted(keys.items())]}
    assert all(k not in json.dumps(body) for k in keys.values())  # fingerprints, not keys
    reset_row = next(r for r in body["rights"] if r["action"] == "reset")
    assert reset_row["levels"] == ["operator", "admin"]
    # no route changes the operators file; a reset needs the operator's own key held by the
    # console (--reset-key), which this one does not hold: nothing is sent
    assert client.put("/api/access", json={}, headers=basic("ada", PASSWORD)).status_code == 405
    r = client.post("/api/reset", headers=basic("ada", PASSWORD))
    assert r.status_code == 403 and "--reset-key" in r.json()["error"], r.json()
    os.chmod(ops, 0o666)  # writable by others: refused as the monitor refuses it
    body = client.get("/api/access").json()
    assert body["reset"]["operators"] == [] and "mode 0666" in body["reset"]["error"]
    none = TestClient(build_app(plain_console(cell_dir))).get("/api/access").json()
    assert "--operators FILE" in none["reset"]["error"]
