"""Scenes of hidden pockets (docs/tracking.md, "Hidden pockets"): persons going behind a 2 m
cabinet inside the protective zone, the cabinet's hidden floor enclosed by floor the camera
sees, or a wall whose hidden floor runs to the image edge (open: no pocket). An operator
confirms the cell clear once at the start; then plain resets every 0.5 s, as the scenario
suite sends (``monitor.replay.scenarios``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig, ResetRequest
from monitor.replay.scenarios import PROTECTIVE, RESET_PERIOD_S, Scenario
from monitor.scene.cell import Block, CellScene, Walker
from monitor.types import Fault, FrameInfo
from monitor.zones import parse_cell

CABINET = Block("cabinet", (0.0, -0.6, 0.0), (0.9, -0.3, 2.0), (60, 80, 150))
# the same fixture line run on to beyond the image's right edge: the floor behind it is open
# to the image edge, a person may come and go there unseen
LONG_WALL = Block("wall", (0.0, -0.6, 0.0), (6.0, -0.3, 2.0), (60, 80, 150))
CONFIRM_AT_S = 0.5  # the operator's confirm-clear: the first reset, before anyone is hidden

# seen on the left, walks behind the cabinet (hidden from about 3 s), stays, steps out to the
# left at 6 s and leaves the zones
INTO_AND_OUT = ((0.0, -2.4, 0.3), (1.0, -2.4, 0.3), (2.5, -0.3, 0.2), (3.0, 0.45, 0.05),
                (6.0, 0.45, 0.05), (6.5, -0.3, 0.2), (8.0, -3.2, 0.3))
# a second person: behind the cabinet from about 5 s, never comes out
INTO_AND_STAY = ((0.0, -2.6, 1.2), (3.0, -2.6, 1.2), (4.5, -0.3, 0.4), (5.0, 0.5, 0.1),
                 (14.0, 0.5, 0.1))


def _beside(path: tuple[tuple[float, float, float], ...], dx: float
            ) -> tuple[tuple[float, float, float], ...]:
    return tuple((t, x + dx, y) for t, x, y in path)


def pocket_scenes(fps: float = 2.0) -> dict[str, Scenario]:
    """The pocket scenes by name."""
    def scene(walkers: tuple[Walker, ...], block: Block = CABINET) -> CellScene:
        return CellScene(walkers, (block,), fps=fps, duration_s=12.0)

    one = Walker(INTO_AND_OUT)
    out = {
        "pocket-out": ("a person hides behind the cabinet and walks out", scene((one,))),
        "pocket-two-one-out": ("two persons go behind the cabinet one after the other, one "
                               "comes out", scene((one, Walker(INTO_AND_STAY)))),
        # side by side, shoulder to shoulder: the detector sees them as one box; one of them
        # comes out again, the other stays hidden
        "pocket-side-by-side": ("two persons go behind the cabinet side by side (one box), "
                                "one comes out",
                                scene((one, Walker((*_beside(INTO_AND_OUT[:4], 0.35),
                                                    (14.0, 0.8, 0.05)))))),
        "open-out": ("a person hides behind a wall running out of the picture and walks "
                     "out", scene((one,), LONG_WALL)),
    }
    return {name: Scenario(name, what, sc, needs=("tracker",), unobserved_ok=True)
            for name, (what, sc) in out.items()}


def _outside_by(p: tuple[float, float]) -> float:
    """How far a floor point lies outside the scenes' protective zone (0: inside)."""
    (x0, y0), (x1, y1) = PROTECTIVE
    return math.hypot(max(x0 - p[0], 0.0, p[0] - x1), max(y0 - p[1], 0.0, p[1] - y1))


@dataclass(frozen=True)
class PocketFrame:
    time_s: float
    state: str
    inside: bool  # ground truth: a person overlaps the protective zone (hidden or not)
    accepted: bool | None  # the reset of this frame (None: none)
    counts: tuple[int | None, ...]  # the camera's pockets' counts after the frame


def run_pocket_scene(scenario: Scenario, detector, confirm_at_s: float = CONFIRM_AT_S,
                     fault_at_s: tuple[float, ...] = (), reference: bool = True
                     ) -> list[PocketFrame]:
    """Every frame through the real pipeline with a reset every 0.5 s, the first at or after
    ``confirm_at_s`` a confirm-clear; the frames at ``fault_at_s`` come with a STOP fault of
    the camera (blinded). ``reference`` False: the monitor has no commissioning reference."""
    cell = parse_cell(scenario.zone_data())
    cam = scenario.scene.camera
    refs = {cam.camera_id: scenario.scene.reference()} if reference else None
    pipe = Pipeline(detector, cam.camera_id, PolicyConfig(), cell, references=refs)
    tracker = pipe.cameras[cam.camera_id].tracker
    radius = cell.spec.person.radius_m
    out, next_reset, confirmed = [], RESET_PERIOD_S, False
    for k, (img, truth) in enumerate(scenario.scene.frames()):
        t = truth.time_s
        reset = None
        if t + 1e-9 >= next_reset:
            confirm = not confirmed and t + 1e-9 >= confirm_at_s
            confirmed |= confirm
            reset = ResetRequest("anna", t, request_id=f"{scenario.name}-{k}",
                                 confirm_clear=confirm)
            next_reset += RESET_PERIOD_S
        fault = tuple(Fault("camera_blinded", f"{cam.camera_id}: contrast too low", True,
                            cam.camera_id) for f in fault_at_s if abs(f - t) < 1e-6)
        res = pipe.process(img, FrameInfo(cam.camera_id, k, t, cam.width, cam.height), t,
                           reset=reset, extra_faults=fault)
        outcome = res.command.reset
        out.append(PocketFrame(
            t, res.command.state, any(_outside_by(p.floor_m) < radius
                                      for p in truth.persons),
            None if outcome is None else outcome.accepted,
            tuple(p.count for p in tracker.pockets.pockets) if tracker else ()))
    return out
