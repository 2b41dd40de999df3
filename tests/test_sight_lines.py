"""Sight lines against occluders, exactly (monitor/geometry/sight.py): a screen thinner than the
gap between two samples of a sight line used to hide nothing.

Found on main at 184015a (2026-12-03): with the sight line sampled at 32 points, a 3 cm
sheet-metal screen 2.2 m tall 5.7 m from the camera left 157 of 205 floor points right behind
it "seen" for a crouching person, and a person walking on behind a 3 cm wall into the
protective zone was out of STOP in 1 (2 fps) and 3 (5 fps) frames. The same screen 30 cm
thick hid all of them. Real components: the scene renderer, the synthetic model, the real
pipeline."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from monitor import zones as zn
from monitor.geometry.occlusion import points_in_volume
from monitor.geometry.sight import segment_through
from monitor.replay import scenarios as sc
from monitor.replay.scenario_run import run_scenario
from monitor.scene.cell import Block, CellScene, Walker, zone_data
from monitor.zones.coverage import figure_visible, occluders_contain


def _screen_cell(thick_m: float) -> zn.Cell:
    screen = Block("screen", (-1.5, -0.3, 0.0), (1.5, -0.3 + thick_m, 2.2))
    data = zone_data(CellScene((), (screen,), fps=5.0, duration_s=1.0))
    for z in data["zones"]:
        if z["kind"] in ("protective", "warning"):
            z["unobserved_ok"] = True  # the screen is meant to hide part of them
    return zn.parse_cell(data)


@pytest.mark.parametrize("thick_m", [0.30, 0.03, 0.01])
def test_the_floor_right_behind_a_screen_is_hidden_however_thin_the_screen(thick_m):
    cell = _screen_cell(thick_m)
    model = cell.camera_models["cam0"]
    contain = occluders_contain(cell.spec.occluder_zones(), cell.meshes)
    # the camera stands at y = -6 m, 3.2 m up: the floor from the screen to 2 m behind it
    grid = np.array([(x, y) for y in np.linspace(0.0, 2.0, 21) for x in np.linspace(-1, 1, 5)])
    p = cell.spec.person
    seen = figure_visible(model, grid, p.smallest_height_m, p.needed_fraction, p.radius_m,
                          contain)
    assert not seen.any(), f"{seen.sum()} of {len(grid)} floor points behind the screen seen"
    # and the floor in front of it stays seen (the exact test hides no more than is hidden)
    front = np.array([(x, y) for y in np.linspace(-2.5, -1.0, 7) for x in np.linspace(-1, 1, 5)])
    assert figure_visible(model, front, p.smallest_height_m, p.needed_fraction, p.radius_m,
                          contain).all()


@pytest.mark.parametrize("fps", [2.0, 5.0])
def test_a_person_walking_on_behind_a_3_cm_wall_into_the_protective_zone_stays_stopped(
        detector, fps):
    wall = Block("wall", (0.3, -0.55, 0.0), (2.9, -0.52, 2.0), (60, 80, 150))
    scenario = sc.Scenario(
        f"thin-wall-{fps:g}fps", "seen in the warning zone, walks on behind a 3 cm wall into "
        "the protective zone", CellScene((Walker(((0.0, 3.1, 0.0), (1.0, 3.1, 0.0),
                                                     (3.0, 0.5, 0.0))),), (wall,), fps=fps,
                                         duration_s=6.0),
        needs=("tracker",), unobserved_ok=True)
    r = run_scenario(scenario, detector)
    assert r.missed_stop_frames == 0 and r.resets_accepted_inside == 0, r
    assert r.holds_at_end_correct == r.holds_at_end == 1, r.end_holds


class _Box:
    shape, id = "box", "b"

    def __init__(self, lo, hi, yaw):
        self.min_m, self.max_m, self.yaw_deg = tuple(lo), tuple(hi), yaw


class _Cylinder:
    shape, id = "cylinder", "c"
    center_m, radius_m, z_min_m, z_max_m = (0.3, -0.2), 0.45, 0.2, 1.7


class _Prism:  # an L-shaped bench: not convex
    shape, id = "extrude", "p"
    points_m = ((-1.0, -1.0), (1.0, -1.0), (1.0, -0.6), (-0.6, -0.6), (-0.6, 1.0), (-1.0, 1.0))
    z_min_m, z_max_m = 0.0, 1.1


class _Mesh:
    shape, id = "mesh", "m"


class _ThinMesh:  # a 1 cm plate turned 40 degrees and leaning: its bounding box is 1.5 m deep
    shape, id = "mesh", "t"


@pytest.mark.parametrize("z", [_Box((-0.5, -0.4, 0.0), (0.7, 0.02, 2.0), 0.0),
                               _Box((-0.5, -0.4, 0.0), (0.7, -0.37, 2.0), 33.0),
                               _Cylinder(), _Prism(), _Mesh(), _ThinMesh()],
                         ids=["box", "thin-box-turned", "cylinder", "l-prism", "mesh",
                              "thin-mesh-turned"])
def test_the_exact_sight_test_finds_every_line_a_dense_sampling_finds(z):
    """Against 4000 samples a line: never free where a sample lies inside (the sampled test
    could only miss), and blocked without a sample inside only for lines grazing the shape
    (fewer than 1 %)."""
    mesh = trimesh.creation.box(extents=(0.8, 0.05, 1.5))
    mesh.apply_translation((0.1, 0.0, 0.75))
    plate = trimesh.creation.box(extents=(1.6, 0.01, 1.8))
    plate.apply_transform(trimesh.transformations.euler_matrix(0.3, 0.0, np.radians(40)))
    plate.apply_translation((0.0, 0.2, 0.9))
    meshes = {"m": (np.asarray(mesh.vertices), np.asarray(mesh.faces)),
              "t": (np.asarray(plate.vertices), np.asarray(plate.faces))}
    rng = np.random.default_rng(11)
    origin = np.array([0.2, -5.0, 3.0])
    ends = np.c_[rng.uniform(-2, 2, 3000), rng.uniform(-2, 3, 3000), rng.uniform(0, 2, 3000)]
    t0, t1 = 1 / 33, 32 / 33
    exact = segment_through(z, origin, ends, t0, t1, meshes)
    t = np.linspace(t0, t1, 4000)
    sampled = np.zeros(len(ends), bool)
    for chunk in np.array_split(np.arange(len(ends)), 30):
        pts = origin + t[None, :, None] * (ends[chunk, None, :] - origin)
        inside = points_in_volume(z, pts.reshape(-1, 3), meshes)
        sampled[chunk] = inside.reshape(len(chunk), -1).any(axis=1)
    assert sampled.sum() > 100, "the shape is in the way of some lines"
    assert not (sampled & ~exact).any(), "a line with a sample inside taken as free"
    assert (exact & ~sampled).sum() <= 0.01 * len(ends), (exact & ~sampled).sum()
