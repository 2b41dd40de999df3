"""A crouching person in the protective zone hidden behind a colleague who stands still in
front of them (2.5-3 m nearer the camera), with or without a detector miss just before: the
floor behind a person standing still is unseen space, as behind a fixture. Before, the lost
person's area ended at its bounded life (and, lost by a miss first, "under seen persons"
took the nearer colleague for them): a reset was accepted with them inside and the cell ran
(8-27 frames out of STOP at 5 fps). monitor/tracking/whereabouts.py: ``covered_s``,
``same_size``."""

from __future__ import annotations

import pytest

from monitor.detector import Detector
from monitor.replay import scenarios as sc
from monitor.replay.scenario_run import Scenario
from monitor.scene.cell import CellScene, Walker

FPS = 5.0


def _scene(gap_m: float, miss_at: float | None) -> Scenario:
    k = round((miss_at or 0.0) * FPS)
    hidden = Walker(((0.0, 0.0, 1.5), (1.5, 0.0, 0.3), (16.0, 0.0, 0.3)),
                    unseen_frames=frozenset(range(k, k + 3)) if miss_at is not None
                    else frozenset(), poses=((2.0, 16.0, "crouching"),))
    colleague = Walker(((0.0, -3.5, 0.3 - gap_m), (4.0, 0.0, 0.3 - gap_m),
                        (16.0, 0.0, 0.3 - gap_m)))
    return Scenario(f"behind-colleague-{gap_m:g}-{miss_at}", "crouching behind a colleague",
                    CellScene((hidden, colleague), fps=FPS, duration_s=16.0),
                    needs=("tracker",), check_false_stops=False)


@pytest.fixture(scope="module")
def detector(synthetic_model):
    return Detector(synthetic_model)


@pytest.mark.parametrize(("gap_m", "miss_at"), [(2.5, None), (3.0, None), (2.5, 2.4),
                                                (3.0, 2.6)])
def test_a_person_hidden_behind_a_colleague_standing_still_keeps_the_stop(
        gap_m, miss_at, detector):
    r = sc.run_scenario(_scene(gap_m, miss_at), detector)
    assert r.missed_stop_frames == 0 and r.resets_accepted_inside == 0
