"""Issue 32, parts 2 and 3: the setup page's zone sets, mute settings and volume corners through
the real app (Starlette's test client, the real zone file, real scrypt passwords, the real audit
log), refused with the zone file loader's own validation (the same one-line message as
``monitor zones mute``), saved as drafts; and the page itself in a real headless chromium: a
login, the zone sets, a floor plan of the volumes, a box corner changed and saved."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from starlette.testclient import TestClient

from monitor import zones as zn
from monitor.console.app import build_app
from monitor.console.auth import hash_password
from monitor.console.zones_api import file_sha
from monitor.zones import load_cell
from monitor.zones.files import draft_path
from tests.console_kit import (
    CHROMIUM,
    ROOT,
    audit_lines,
    basic,
    chromium,
    plain_console,
    serving,
    zone_file,
)

PASSWORD = "a long console password"
USERS = {"vera": "viewer", "otto": "operator", "ada": "admin"}
SETS = [{"id": "normal", "zones": ["robot-protective", "robot-warning", "cam0-protective",
                                   "cam0-warning"]},
        {"id": "teach", "name": "Teaching", "zones": ["robot-protective", "cam0-protective"],
         "speed_scale": 0.2}]
SHOTS = ROOT / "docs" / "console" if os.environ.get("UPDATE_CONSOLE_SHOTS") == "1" else \
    Path(tempfile.gettempdir()) / "console-shots"


@pytest.fixture(scope="module")
def password_lines() -> str:
    """The passwords file's text, hashed once for the module (scrypt is slow on purpose)."""
    return "".join(f"{n}:{lv}:{hash_password(PASSWORD)}\n" for n, lv in USERS.items())


@pytest.fixture
def cell_dir(tmp_path, password_lines):
    """The demo cell with two zone sets and their rules, and the passwords file."""
    path = zone_file(tmp_path)
    data = zn.read_cell_document(path)
    data["sets"] = SETS
    data["default_set"] = "normal"
    data["transitions"] = [["normal", "teach"], ["teach", "normal"]]
    zn.write_cell_data(data, path)
    (tmp_path / "pw").write_text(password_lines)
    os.chmod(tmp_path / "pw", 0o600)
    return tmp_path


ADMIN = basic("ada", PASSWORD)


def test_the_setup_shows_sets_rules_mutes_and_volumes(cell_dir):
    client = TestClient(build_app(plain_console(cell_dir)))
    d = client.get("/api/setup").json()
    assert [(s["id"], s["default"], s["speed_scale"]) for s in d["sets"]] == [
        ("normal", True, None), ("teach", False, 0.2)]
    assert d["rules"] == {"default_set": "normal", "switch_over_s": 1.0,
                          "selector_ttl_s": None,
                          "transitions": [["normal", "teach"], ["teach", "normal"]]}
    assert {m["id"]: m["describe"] for m in d["mutes"]}["robot-protective"] == \
        "no mute rule: never muted"
    vols = {v["id"]: v for v in d["volumes"]}
    box = vols["robot-protective"]
    assert box["editable"] and box["min_m"] == [-1.0, -1.0, 0.0] and \
        box["max_m"] == [1.0, 1.0, 2.2]
    assert sorted(map(tuple, box["outline_m"])) == [(-1, -1), (-1, 1), (1, -1), (1, 1)]
    assert "editable" not in vols["robot-warning"]  # an extrusion: shown, not edited here
    assert len(vols["robot-warning"]["outline_m"]) == 4
    assert d["sha"] == file_sha(cell_dir / "cell.yaml")


def test_a_mute_edit_uses_the_cli_validation_and_is_a_draft(cell_dir):
    client = TestClient(build_app(plain_console(cell_dir)))
    cell = cell_dir / "cell.yaml"
    r = client.put("/api/setup/mute/robot-protective", headers=ADMIN,
                   json={"operators": ["anna", "bert"], "max_s": 120, "as": "warning",
                         "speed_scale": 0.1})
    # made mutable: weaker, so it waits as the draft for a signed apply (issue 48)
    assert r.status_code == 202, r.text
    assert "draft" in r.json()["note"] and "signed apply" in r.json()["note"]
    draft = draft_path(cell)
    assert load_cell(cell).zone("robot-protective").mute is None
    mute = load_cell(draft).zone("robot-protective").mute
    assert (mute.operators, mute.max_s, mute.speed_scale) == (("anna", "bert"), 120.0, 0.1)
    before, draft_before = cell.read_bytes(), draft.read_bytes()
    # longer than a mute may be: refused by the zone file's validation, nothing written
    r = client.put("/api/setup/mute/robot-protective", headers=ADMIN,
                   json={"max_s": 7200})
    assert r.status_code == 422
    console_error = r.json()["error"]
    assert "max_s" in console_error and "3600" in console_error and "\n" not in console_error
    assert cell.read_bytes() == before
    # the command line refuses it with the same words
    proc = subprocess.run([sys.executable, "-m", "monitor", "zones", "mute", str(draft),
                           "robot-protective", "--max-s", "7200"], capture_output=True,
                          text=True, timeout=60)
    words = console_error.split(": ", 1)[1]  # after the file's name (the draft's here)
    assert proc.returncode == 2 and words in proc.stderr, proc.stderr
    for body, words in [
        ({"unmutable": True, "max_s": 10}, "give either --operators/--max-s (allow), "
                                           "--unmutable or --remove"),
        ({"as": "off"}, "as 'off': one of warning, none"),
        ({}, "nothing to change"),
    ]:
        r = client.put("/api/setup/mute/robot-protective", headers=ADMIN, json=body)
        assert r.status_code == 422 and words in r.json()["error"], r.text
    r = client.put("/api/setup/mute/" + "z" * 300, headers=ADMIN, json={"remove": True})
    assert r.status_code == 400 and "zone id 'zzzzzzzzzzzzzzzzzzzz... (300 characters)'" in \
        r.json()["error"]
    assert audit_lines(cell_dir)[-1]["result"] == "bad_request"
    r = client.put("/api/setup/mute/no-such-zone", headers=ADMIN, json={"remove": True})
    assert r.status_code == 422 and "no zone 'no-such-zone'" in r.json()["error"]
    for body in ({"max_s": "60"}, {"operators": "anna"}, {"unmutable": 1},
                 {"max_s": 60, "colour": "red"}):
        r = client.put("/api/setup/mute/robot-protective", headers=ADMIN, json=body)
        assert r.status_code == 400, (body, r.text)
    assert cell.read_bytes() == before and draft.read_bytes() == draft_before
    # made unmutable again: no weaker than the zone file, so into it, and the draft goes
    r = client.put("/api/setup/mute/robot-protective", headers=ADMIN, json={"unmutable": True})
    assert r.status_code == 200 and load_cell(cell).zone("robot-protective").unmutable
    assert not draft.exists()
    results = [(e["edit"], e["result"]) for e in audit_lines(cell_dir)]
    assert results[0] == ("edit_mute", "draft") and results[-1] == ("edit_mute", "saved")
    assert ("edit_mute", "invalid") in results and ("edit_mute", "bad_request") in results


def test_set_rules_are_edited_with_the_zone_file_rules(cell_dir):
    client = TestClient(build_app(plain_console(cell_dir)))
    cell = cell_dir / "cell.yaml"
    r = client.put("/api/setup/rules", headers=ADMIN,
                   json={"allow": [["normal", "teach"]], "switch_over_s": 2.5,
                         "default_set": "teach", "selector_ttl_s": 5})
    assert r.status_code == 202, r.text  # rules changed: not proved stronger, a draft
    draft = draft_path(cell)
    spec = load_cell(draft).spec
    assert (spec.transitions, spec.switch_over_s, spec.default_set, spec.selector_ttl_s) == (
        (("normal", "teach"),), 2.5, "teach", 5.0)
    before = draft.read_bytes()
    for body, words in [({"default_set": "nosuch"}, "nosuch"),
                        ({"switch_over_s": 100}, "switch_over_s"),
                        ({"allow": [["normal", "ghost"]]}, "ghost"),
                        ({"any": True, "none": True}, "give one of --allow, --any or --none")]:
        r = client.put("/api/setup/rules", headers=ADMIN, json=body)
        assert r.status_code == 422 and words in r.json()["error"], (body, r.text)
    assert client.put("/api/setup/rules", headers=ADMIN,
                      json={"allow": [["a", "b", "c"]]}).status_code == 400
    assert draft.read_bytes() == before
    r = client.put("/api/setup/rules", headers=ADMIN, json={"any": True,
                                                            "no_selector_ttl": True})
    assert r.status_code == 202
    assert load_cell(draft).spec.transitions is None


def test_box_corners_are_edited_in_metres_and_bad_corners_are_refused(cell_dir):
    client = TestClient(build_app(plain_console(cell_dir)))
    cell = cell_dir / "cell.yaml"
    r = client.put("/api/setup/volume/robot-protective", headers=ADMIN,
                   json={"min_m": [-1.2, -1.0, 0], "max_m": [1.5, 1.0, 2.4]})
    assert r.status_code == 200, r.text  # grown: no weaker, into the zone file
    box = load_cell(cell).zone("robot-protective")
    assert (box.min_m, box.max_m) == ((-1.2, -1.0, 0.0), (1.5, 1.0, 2.4))
    before = cell.read_bytes()
    nan = b'{"min_m": [NaN, 0, 0], "max_m": [1, 1, 1]}'
    r = client.put("/api/setup/volume/robot-protective", content=nan,
                   headers={**ADMIN, "content-type": "application/json"})
    assert r.status_code == 400 and "finite" in r.json()["error"]
    huge = b'{"min_m": [0, 0, 0], "max_m": [1e400, 1, 1]}'
    r = client.put("/api/setup/volume/robot-protective", content=huge,
                   headers={**ADMIN, "content-type": "application/json"})
    assert r.status_code == 400 and "out of range" in r.json()["error"]
    for body, status, words in [
        ({"min_m": [1, 0, 0], "max_m": [-1, 1, 1]}, 422, "box min_m.x >= max_m.x (1 >= -1 m)"),
        ({"min_m": [0, 0, 2], "max_m": [1, 1, 1]}, 422, "z_min >= z_max (2 >= 1 m)"),
        ({"min_m": [0, 0], "max_m": [1, 1, 1]}, 400, "min_m: [x, y, z] in metres"),
        ({"min_m": [0, 0, None], "max_m": [1, 1, 1]}, 400, "min_m: [x, y, z] in metres"),
        ({"max_m": [1, 1, 1]}, 400, "min_m: [x, y, z] in metres"),
    ]:
        r = client.put("/api/setup/volume/robot-protective", headers=ADMIN, json=body)
        assert r.status_code == status and words in r.json()["error"], (body, r.text)
    r = client.put("/api/setup/volume/robot-warning", headers=ADMIN,
                   json={"min_m": [0, 0, 0], "max_m": [1, 1, 1]})
    assert r.status_code == 422 and "is no box in the cell frame" in r.json()["error"]
    r = client.put("/api/setup/volume/robot-protective", headers=ADMIN,
                   json={"min_m": [0, 0, 0], "max_m": [1, 1, 1], "base": "0" * 64})
    assert r.status_code == 422 and "changed since this page loaded" in r.json()["error"]
    r = client.put("/api/setup/volume/robot-protective", headers=basic("otto", PASSWORD),
                   json={"min_m": [0, 0, 0], "max_m": [1, 1, 1]})
    assert r.status_code == 403 and "needs the admin level" in r.json()["error"]
    assert cell.read_bytes() == before
    invalid = [e for e in audit_lines(cell_dir) if e["result"] in ("invalid", "bad_request")]
    assert len(invalid) == 9 and all(e["edit"] == "edit_volume" for e in invalid)


# --- the page in a real browser -------------------------------------------------------------

def _wait(driver, condition, what: str, ceiling: float = 30.0):
    deadline = time.monotonic() + ceiling
    while time.monotonic() < deadline:
        found = condition(driver)
        if found:
            return found
        time.sleep(0.1)
    raise AssertionError(f"{what} did not appear within {ceiling:g} s")


@pytest.mark.slow
@pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium missing")
def test_the_setup_page_in_a_browser_logs_in_shows_sets_and_a_floor_plan_and_saves_a_box(
        cell_dir):
    from selenium.webdriver.common.by import By

    cell = cell_dir / "cell.yaml"
    console = plain_console(cell_dir, view_login=True)  # as off loopback: viewing needs a login
    with serving(console) as url, chromium(cell_dir / "profile") as driver:
        driver.get(url + "/setup")
        _wait(driver, lambda d: "needs a login" in d.find_element(By.ID, "message").text,
              "the login request")
        driver.find_element(By.ID, "user").send_keys("ada")
        driver.find_element(By.ID, "password").send_keys(PASSWORD)
        driver.find_element(By.ID, "login").click()
        _wait(driver, lambda d: d.find_elements(By.CSS_SELECTOR, "#sets tr[data-set]"),
              "the zone sets")
        assert driver.find_element(By.ID, "whoami").text == "ada (admin)"
        rows = driver.find_elements(By.CSS_SELECTOR, "#sets tr[data-set]")
        assert [r.get_attribute("data-set") for r in rows] == ["normal", "teach"]
        assert driver.find_element(By.ID, "transitions").get_attribute("value") == \
            "normal:teach, teach:normal"
        plan = driver.find_elements(By.CSS_SELECTOR, "#plan polygon.volume")
        assert sorted(p.get_attribute("data-id") for p in plan) == ["robot-protective",
                                                                     "robot-warning"]
        before = driver.find_element(
            By.CSS_SELECTOR, "#plan polygon[data-id='robot-protective']").get_attribute("points")
        field = driver.find_element(By.CSS_SELECTOR,
                                    "#boxes tr[data-zone='robot-protective'] input[name=max_x]")
        field.clear()
        field.send_keys("1.6")
        after = driver.find_element(
            By.CSS_SELECTOR, "#plan polygon[data-id='robot-protective']").get_attribute("points")
        assert after != before and "1.6" in after  # the plan follows the numbers
        SHOTS.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(SHOTS / "setup-volumes.png"))
        driver.execute_script("window.scrollTo(0, 0)")
        driver.save_screenshot(str(SHOTS / "setup.png"))
        driver.find_element(By.CSS_SELECTOR,
                            "#boxes tr[data-zone='robot-protective'] button.save").click()
        _wait(driver, lambda d: "saved robot-protective" in d.find_element(
            By.ID, "message").text, "the saved message")
        assert "draft" in driver.find_element(By.ID, "message").text
        assert driver.find_elements(By.CSS_SELECTOR, "#resetters tr") == []
    assert load_cell(cell).zone("robot-protective").max_m == (1.6, 1.0, 2.2)
