"""Attacks on the ways the monitor lets go of a hold (docs/tracking.md, "Hidden pockets",
"Lost persons"): generated scenes a real cell could produce, run through the real pipeline
(synthetic model, zone check, tracker, policy) with a confirm-clear at 0.5 s and then a plain
reset every 0.5 s (``monitor.replay.pocket_scenes.run_pocket_scene``). Every frame with a
person inside the protective zone, hidden or not, must be STOP and refuse the reset."""

from __future__ import annotations

from monitor.policy import STOP
from monitor.replay.pocket_scenes import CABINET, run_pocket_scene
from monitor.replay.scenarios import Scenario
from monitor.scene.cell import CellScene, Walker

# walks in from the front left, passes in front of a colleague standing behind the cell, and
# steps behind the cabinet (hidden from 3 s) while the detector still boxes the two as one
INTO_POCKET = ((0.0, -2.6, 1.2), (1.0, -2.6, 1.2), (2.5, -0.3, 0.4), (3.0, 0.5, 0.1),
               (30.0, 0.5, 0.1))
# the colleague: stands behind the cell (outside the protective zone) until 3 s, then walks
# through the zone, past the cabinet's left side, and out of the cell to the front left
BEHIND_THE_CELL = ((0.0, -0.3, 2.5), (3.0, -0.3, 2.5), (5.0, -0.3, 0.2), (6.0, -0.3, -0.6),
                   (8.0, -3.0, -3.0))


def _scenario(name: str, walkers: tuple[Walker, ...], duration_s: float) -> Scenario:
    return Scenario(name, name, CellScene(walkers, (CABINET,), fps=2.0,
                                          duration_s=duration_s),
                    needs=("tracker",), unobserved_ok=True)


def _violations(frames) -> list[str]:
    out = []
    for f in frames:
        if f.inside and f.state != STOP:
            out.append(f"{f.time_s} s: {f.state} with a person inside")
        if f.inside and f.accepted:
            out.append(f"{f.time_s} s: reset accepted with a person inside")
    return out


def test_a_person_going_behind_the_cabinet_while_boxed_with_a_colleague_stays_held(detector):
    """The person walks in front of a colleague standing behind the cell: for two frames the
    detector boxes both as one (the person's track is lost into the colleague's box, "hidden
    right behind them"), and in the next frame the person is behind the cabinet. The
    colleague then walks through the zone and out. Before: the place the swallowed track
    stood did not move with the box that swallowed it, so nothing followed the person behind
    the cabinet; once the colleague had left, a plain reset was accepted at 7 s and the
    robot ran from 9 s with the person behind the cabinet (also without any confirm-clear:
    no pocket is needed for it)."""
    scenario = _scenario("swallowed-then-hidden",
                         (Walker(INTO_POCKET), Walker(BEHIND_THE_CELL, height_m=1.9)), 11.0)
    frames = run_pocket_scene(scenario, detector)
    assert not _violations(frames), _violations(frames)
    frames = run_pocket_scene(scenario, detector, confirm_at_s=100.0)  # no confirm-clear
    assert not _violations(frames), _violations(frames)
