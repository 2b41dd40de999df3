"""Mesh zones (STL) hold a person with no surface contact too: FCL tests mesh surfaces only, so a
person wholly inside a large mesh zone, or a small mesh zone wholly inside a person's cylinder,
must still be a hit (cases from mutation testing of monitor/zones/check.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml

from monitor.config import demo_cell_path
from monitor.scene import DEMO_CAMERA
from monitor.zones import check_persons, load_cell


def person_box(x: float, y: float, height_m: float = 1.75) -> np.ndarray:
    """The demo camera's box of a person standing at floor point (x, y)."""
    (fu, fv), (_, hv) = DEMO_CAMERA.project(np.array([[x, y, 0.0], [x, y, height_m]]))
    half = 0.2 * (fv - hv)
    return np.array([[fu - half, hv, fu + half, fv]])


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("mesh")
    # a room-sized zone: 1.5 x 1 m around its centre, from below the floor to 2.5 m, so a
    # person standing at its centre touches none of its faces (FCL sees surfaces only)
    big = trimesh.creation.box(extents=(3.0, 2.0, 3.0))
    big.apply_translation((1.8, -1.5, 1.0))
    big.export(tmp / "big.stl")
    small = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    small.apply_translation((-1.8, -1.5, 0.1))  # a pedal-sized zone on the floor
    small.export(tmp / "small.stl")
    data = yaml.safe_load(demo_cell_path().read_text())
    data["zones"] = [
        # its right end lies outside the image: accepted explicitly (tests/test_coverage.py)
        {"id": "room", "kind": "protective", "shape": "mesh", "file": "big.stl",
         "unobserved_ok": True},
        {"id": "pedal", "kind": "warning", "shape": "mesh", "file": "small.stl",
         "speed_scale": 0.3},
    ]
    path = Path(tmp) / "cell.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return load_cell(path)


def zones_hit(cell, x: float, y: float) -> set[str]:
    report = check_persons(cell, "cam0", person_box(x, y), foot_band_px=(0.0, 0.0))
    return {h.zone_id for h in report.hits}


def test_a_person_wholly_inside_a_large_mesh_zone_is_in_it(cell):
    assert zones_hit(cell, 1.8, -1.5) == {"room"}


def test_a_small_mesh_zone_wholly_inside_the_person_is_hit(cell):
    assert zones_hit(cell, -1.8, -1.5) == {"pedal"}


@pytest.mark.parametrize(("x", "y"), [(-1.8, -3.0), (-0.4, -1.5), (4.0, -1.5)])
def test_persons_away_from_the_mesh_zones_hit_nothing(cell, x, y):
    assert zones_hit(cell, x, y) == set()
