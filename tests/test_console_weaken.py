"""Issue 48: a zone change from the console that weakens protection (a protective zone removed,
shrunk, made a mask or mutable, a mask added ...) never reaches the zone file a restart loads:
it waits as a draft for an operator's signed apply, and it is an incident of its own. The pure
rule (``monitor.zones.weaken``), and the real app over a real recorder data dir (Starlette's
test client). The signed apply that promotes the draft in a running ``monitor run``:
``tests/test_zone_apply.py::test_a_console_save_that_shrinks_a_protective_zone_has_no_effect_until_a_signed_apply``."""

from __future__ import annotations

import copy
import json

import pytest
from starlette.testclient import TestClient

from monitor.console.app import build_app
from monitor.console.auth import set_password
from monitor.incidents import IncidentIndex
from monitor.zones import load_cell
from monitor.zones.files import draft_path, parse_cell, promote_draft, read_cell_data
from monitor.zones.weaken import cell_weakenings
from tests.console_kit import OPERATOR, PASSWORD, ROOT, basic, make_console

PROTECTIVE = [[485.6, 532.0], [794.4, 532.0], [757.1, 403.5], [522.9, 403.5]]  # cam0-protective
SMALLER = [[560.0, 532.0], [700.0, 532.0], [700.0, 450.0], [560.0, 450.0]]
LARGER = [[470.0, 540.0], [810.0, 540.0], [770.0, 395.0], [510.0, 395.0]]


def _demo() -> dict:
    return read_cell_data(ROOT / "zones" / "demo-cell.yaml")


def _zone(data: dict, zone_id: str) -> dict:
    return next(z for z in data["zones"] if z["id"] == zone_id)


def _weakens(change) -> list[str]:
    old = _demo()
    new = copy.deepcopy(old)
    change(new)
    return cell_weakenings(parse_cell(old), parse_cell(new))


def test_what_weakens_protection():
    assert _weakens(lambda d: None) == []
    assert _weakens(lambda d: _zone(d, "cam0-protective").update(points_px=LARGER)) == []
    assert _weakens(lambda d: d["zones"].append(
        {"id": "more", "kind": "protective", "shape": "box", "min_m": [3, 3, 0],
         "max_m": [4, 4, 2]})) == []
    assert _weakens(lambda d: _zone(d, "cam0-protective").update(points_px=SMALLER)) == [
        "protective zone cam0-protective shrunk or moved (some of what it covered is no "
        "longer covered)"]
    assert _weakens(lambda d: _zone(d, "cam0-protective").update(kind="mask")) == [
        "protective zone cam0-protective made a mask zone"]
    assert _weakens(lambda d: _zone(d, "robot-protective").update(
        min_m=[-0.5, -1.0, 0.0])) == ["protective zone robot-protective shrunk or moved (some "
                                      "of what it covered is no longer covered)"]
    assert _weakens(lambda d: _zone(d, "robot-protective").update(
        min_m=[-2.0, -2.0, 0.0], max_m=[2.0, 2.0, 2.5])) == []  # grown: not weaker
    assert _weakens(lambda d: _zone(d, "robot-protective").update(
        mute={"max_s": 60, "operators": ["anna"]})) == [
        "protective zone robot-protective made mutable (or more mutable)"]
    assert _weakens(lambda d: d["zones"].remove(_zone(d, "robot-protective"))) == [
        "protective zone robot-protective removed"]
    assert _weakens(lambda d: _zone(d, "robot-protective").update(enabled=False)) == [
        "protective zone robot-protective disabled"]
    assert _weakens(lambda d: _zone(d, "poster-mask").update(
        points_px=[[40.0, 80.0], [400.0, 80.0], [400.0, 600.0], [40.0, 600.0]])) == [
        "mask poster-mask grown or moved (a mask hides the persons in it)"]
    assert _weakens(lambda d: _zone(d, "cam0-warning").update(speed_scale=0.9)) == [
        "warning zone cam0-warning allows more speed (0.3 -> 0.9)"]
    assert _weakens(lambda d: d["zones"].append(
        {"id": "m2", "kind": "mask", "shape": "polygon", "camera": "cam0",
         "points_px": [[500, 420], [700, 420], [700, 520], [500, 520]]})) == [
        "mask m2 added (a mask hides the persons in it)"]


@pytest.fixture()
def console(tmp_path):
    c = make_console(tmp_path)
    set_password(tmp_path / "console.passwords", "ada", PASSWORD, "admin")
    return c


def test_a_shrinking_save_waits_as_a_draft_and_is_an_incident_of_its_own(console, tmp_path):
    client = TestClient(build_app(console))
    cell = tmp_path / "cell.yaml"
    before = cell.read_bytes()
    in_file = load_cell(cell).config_hash
    data_dir = tmp_path / "incidents"
    incidents_before = len(IncidentIndex(data_dir).list())
    base = client.get("/api/zones").json()["sha"]
    r = client.put("/api/zones/cam0-protective", json={"points_px": SMALLER, "base": base},
                   headers=basic(OPERATOR, PASSWORD))
    assert r.status_code == 202, r.text
    out = r.json()
    draft = draft_path(cell)
    assert cell.read_bytes() == before  # the file a restart loads: untouched
    assert out["draft"] == {"file": str(draft), "weakens": [
        "protective zone cam0-protective shrunk or moved (some of what it covered is no longer "
        "covered)"]}
    assert "monitor zones apply --zones" in out["note"] and "commission" in out["note"]
    assert out["audit"]["result"] == "draft" and out["audit"]["weakens"]
    assert load_cell(draft).zone("cam0-protective").points_px == tuple(map(tuple, SMALLER))
    # two incidents: the edit, and the weakening of its own
    rows = IncidentIndex(data_dir).list()
    assert len(rows) == incidents_before + 2
    weak = next(i for i in rows if i.id == out["weakened_incident"])
    assert weak.record["causes"] == ["zone_weakened"]
    assert "weakens protection" in weak.record["describe"]
    assert weak.record["zone_edit"]["in_force_after_signed_apply"] is True
    state = client.get("/api/state").json()
    assert state["zone_draft"]["weakens"] == out["draft"]["weakens"]
    assert state["zone_file_hash"] == in_file
    # the editor shows the draft (edits go on from it); a further edit that still weakens: draft
    listed = client.get("/api/zones").json()
    assert listed["draft"]["file"] == str(draft)
    shown = next(p for p in listed["polygons"] if p["id"] == "cam0-protective")
    assert shown["points_px"] == SMALLER
    r = client.put("/api/zones/cam0-protective", json={"kind": "mask", "points_px": SMALLER,
                                                       "base": listed["sha"]},
                   headers=basic(OPERATOR, PASSWORD))
    assert r.status_code == 202 and "made a mask zone" in r.json()["draft"]["weakens"][0]
    assert cell.read_bytes() == before
    # the setup page's edits follow the same rule: a box moved, a protective zone mutable
    setup = client.get("/api/setup").json()
    r = client.put("/api/setup/volume/robot-protective", json={
        "min_m": [0.0, -1.0, 0.0], "max_m": [2.0, 1.0, 2.2], "base": setup["sha"]},
        headers=basic("ada", PASSWORD))
    assert r.status_code == 202, r.text
    assert any("robot-protective shrunk or moved" in w for w in r.json()["draft"]["weakens"])
    assert cell.read_bytes() == before
    # undone (the polygon back as it was, the box back): nothing weaker waits: into the file
    listed = client.get("/api/zones").json()
    r = client.put("/api/zones/cam0-protective", json={
        "kind": "protective", "points_px": PROTECTIVE, "base": listed["sha"]},
        headers=basic(OPERATOR, PASSWORD))
    assert r.status_code == 202  # the moved box still waits
    setup = client.get("/api/setup").json()
    r = client.put("/api/setup/volume/robot-protective", json={
        "min_m": [-1.0, -1.0, 0.0], "max_m": [1.0, 1.0, 2.2], "base": setup["sha"]},
        headers=basic("ada", PASSWORD))
    assert r.status_code == 200 and r.json()["draft"] is None, r.text
    assert not draft.exists() and client.get("/api/state").json()["zone_draft"] is None
    audit = [json.loads(line) for line in (tmp_path / "audit.jsonl").read_text().splitlines()]
    assert [e["result"] for e in audit if e.get("result") in ("saved", "draft")] == [
        "draft", "draft", "draft", "draft", "saved"]


def test_a_draft_becomes_the_zone_file_only_with_the_signed_hash(tmp_path):
    cell = tmp_path / "cell.yaml"
    cell.write_bytes((ROOT / "zones" / "demo-cell.yaml").read_bytes())
    before = cell.read_bytes()
    data = read_cell_data(cell)
    _zone(data, "cam0-protective")["points_px"] = SMALLER
    draft = draft_path(cell)
    from monitor.zones.files import write_cell_data

    signed = write_cell_data(data, draft).config_hash
    with pytest.raises(Exception, match="the draft changed after you signed"):
        promote_draft(cell, "0" * 64)
    assert cell.read_bytes() == before and draft.exists()
    promoted = promote_draft(cell, signed)
    assert promoted.config_hash == signed == load_cell(cell).config_hash
    assert not draft.exists() and cell.with_name("cell.yaml.bak").read_bytes() == before
