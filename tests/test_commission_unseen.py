"""The commissioning report's unseen floor (issue 46): each region of a protective or warning
zone no camera sees, with its availability cost (floor area, share of the zone), what hides it
and a camera position that would see it, judged with the monitor's own visibility test; and
the report's section, signed over every byte with the rest."""

from __future__ import annotations

import dataclasses

import pytest

from monitor.commission import report_details as d
from monitor.commission.floor import zone_floors
from monitor.commission.unseen import unseen_regions
from monitor.replay import scenarios as sc
from monitor.scene.cell import zone_data
from monitor.zones import parse_cell

EVIDENCE = {s.name: s for s in sc.evidence_scenarios()}


@pytest.fixture(scope="module")
def cabinet_cell():
    return parse_cell(EVIDENCE["stranger-2fps"].zone_data())


def test_the_floor_behind_the_cabinet_is_listed_with_its_cost_and_a_camera_that_sees_it(
        cabinet_cell):
    regions = unseen_regions(cabinet_cell)
    prot = [r for r in regions if r["zone"] == "robot-protective"]
    assert prot and prot[0]["hidden_by"] == "behind cabinet"
    floor = next(f for f in zone_floors(cabinet_cell) if f.zone_id == "robot-protective")
    blind = int((~floor.visible).sum())
    assert sum(r["cells"] for r in prot) == blind
    r = prot[0]
    assert r["area_m2"] == pytest.approx(r["cells"] * floor.cell_m ** 2, abs=0.01)
    assert r["share"] == pytest.approx(r["cells"] / len(floor.centres_m), abs=0.001)
    cam = r["camera"]
    assert cam["sees_share"] >= 0.9
    # the cabinet stands between cam0 (at -y) and the region: the camera looks from +y
    assert "+y" in cam["from_side"] and cam["position_m"][1] > r["middle_m"][1]


def test_a_camera_at_the_suggested_position_sees_the_region(cabinet_cell):
    """Adding a camera where the report suggests (cam0's lens, looking at the region) to the
    zone file leaves that floor seen: the region is gone from the list."""
    r = next(x for x in unseen_regions(cabinet_cell) if x["zone"] == "robot-protective")
    scene = EVIDENCE["stranger-2fps"].scene
    from monitor.scene import Camera

    base = scene.camera
    cam1 = Camera.look_at("cam1", (base.width, base.height), base.K,
                          tuple(r["camera"]["position_m"]), (*r["camera"]["looking_at_m"], 0.0))
    data = zone_data(scene)
    data["cameras"] += zone_data(dataclasses.replace(scene, camera=cam1))["cameras"]
    after = unseen_regions(parse_cell(data))
    left = sum(x["cells"] for x in after if x["zone"] == "robot-protective")
    assert left <= r["cells"] * (1 - r["camera"]["sees_share"]) + 1e-9, after


def test_open_floor_has_no_unseen_region():
    scenario = EVIDENCE["stranger-2fps"]
    open_cell = parse_cell(zone_data(dataclasses.replace(scenario.scene, blocks=())))
    assert not [r for r in unseen_regions(open_cell) if r["hidden_by"] == "behind cabinet"]


def test_the_report_section_names_each_region_its_cost_and_the_camera(cabinet_cell):
    html = d.unseen(unseen_regions(cabinet_cell))
    assert 'id="unseen"' in html and "behind cabinet" in html
    assert "m\u00b2" in html and "would see" in html and "from the +y" in html
    assert "Every cell" in d.unseen([])


def test_the_demo_report_has_the_section_and_stays_signed(tmp_path):
    from monitor.cli import main
    from monitor.commission.report import verify
    from tests.helpers import commissioner_key

    out = tmp_path / "demo.html"
    key = commissioner_key(tmp_path, "anna")
    assert main(["commission", "report", "--out", str(out), "--by", "anna", "--key",
                 str(key)]) == 0
    data = out.read_bytes()
    assert b'<section id="unseen">' in data
    assert verify(data).valid  # signed over every byte, the new section too
    start = data.index(b'<section id="unseen">')
    tampered = data[:start + 30] + b"X" + data[start + 31:]
    assert not verify(tampered).valid


def test_zones_preview_names_the_unseen_floor_its_cost_and_a_camera(tmp_path, capsys):
    import cv2
    import yaml

    from tests.helpers import zones_cli

    scenario = EVIDENCE["stranger-2fps"]
    zones = tmp_path / "cell.yaml"
    zones.write_text(yaml.safe_dump(scenario.zone_data()))
    img, _ = next(iter(scenario.scene.frames()))
    frame = tmp_path / "frame.png"
    cv2.imwrite(str(frame), img)
    assert zones_cli("preview", zones, "--frame", frame, "--out", tmp_path / "p.png") == 0
    text = capsys.readouterr().out
    line = next(x for x in text.splitlines() if "zone robot-protective" in x)
    assert "behind cabinet" in line and "m^2" in line and "% of the zone" in line, line
    assert "waiting never ends a hold there" in line and "from the +y side" in line, line


@pytest.mark.parametrize("name, pockets", [("pocket-out", 1), ("open-out", 0)])
def test_zones_preview_outlines_the_hidden_pockets(tmp_path, capsys, name, pockets):
    # the cabinet's hidden floor is enclosed by seen floor (a pocket: outlined in the pocket
    # colour, as the replay draws it); the wall's runs to the image edge (none)
    import cv2
    import numpy as np
    import yaml

    from monitor.records.areas_draw import POCKET_BGR
    from monitor.replay.pocket_scenes import pocket_scenes
    from tests.helpers import zones_cli

    scenario = pocket_scenes()[name]
    zones = tmp_path / "cell.yaml"
    zones.write_text(yaml.safe_dump(scenario.zone_data()))
    img, _ = next(iter(scenario.scene.frames()))
    frame = tmp_path / "frame.png"
    cv2.imwrite(str(frame), img)
    out = tmp_path / "p.png"
    assert zones_cli("preview", zones, "--frame", frame, "--out", out) == 0
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("pocket ")]
    assert len(lines) == pockets, lines
    drawn = cv2.imread(str(out))
    cyan = np.all(np.abs(drawn.astype(int) - np.array(POCKET_BGR)) <= 8, axis=2)
    assert (cyan.sum() > 50) == bool(pockets), cyan.sum()
