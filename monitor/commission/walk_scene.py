"""A generated commissioning walk with ground truth: the walk docs/commissioning.md asks for,
in the scenario suite's cell (``monitor.replay.scenarios``: the 2 x 2 m protective box around the
robot, the 5 x 5 m warning square, camera ``cam0`` 6 m in front, 640x360).

The person walks around the protective zone 0.7 m outside its boundary and, at each corner,
steps in onto the corner's floor cell, crouches (head at 0.58 of their height), stands up and
steps out again: four entries, each with a crouch in the zone's corner. ``hidden_corner`` puts
a 1.9 m cabinet in front of the zone's near-left quarter: a person crouching at the far-left
corner is hidden behind it, and the walk must say so (blind cells there, not seen).
``late_detection_walk``: a person first in the zone in a frame the detector misses.

``write_walk_scene`` writes what ``monitor commission walk --video`` takes: the video, its zone
file and its ground truth (``--truth``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from monitor.commission.truth import TRUTH_FILE, truth_of, write_truth
from monitor.replay.scenarios import PROTECTIVE, Scenario
from monitor.scene import write_video
from monitor.scene.cell import Block, CellFrameTruth, CellScene, Walker
from monitor.zones import write_cell_data

OUTSIDE_M = 0.7  # the walk around the zone: this far outside its boundary
CORNER_INSET_M = 0.125  # the crouch: on the corner floor cell's centre (0.25 m cells)
STEP_S = 0.8  # stepping in from the outside point to the corner, and out again
CROUCH_S = 1.0
WALK_MPS = 1.6
# 1.9 m high, in front of the zone's near-left quarter: a crouching person at the far-left
# corner is hidden behind it (a standing one shows their head over it)
CABINET = Block("cabinet", (-1.0, -1.5, 0.0), (-0.1, -1.1, 1.9))
HIDDEN_CORNER = 3  # index into the corners: far-left
VIDEO_FILE = "walk.mp4"
ZONES_FILE = "cell.yaml"


@dataclass(frozen=True)
class CornerVisit:
    corner_m: tuple[float, float]  # the zone's corner
    crouch_m: tuple[float, float]  # where the person crouches (inside the zone)
    crouch_s: tuple[float, float]  # from, to


def zone_corners() -> tuple[tuple[float, float], ...]:
    """The protective zone's corners: near-left, near-right, far-right, far-left (the camera
    looks along +y)."""
    (x0, y0), (x1, y1) = PROTECTIVE
    return ((x0, y0), (x1, y0), (x1, y1), (x0, y1))


def corner_walk(hidden_corner: bool = False, visits: tuple[int, ...] = (0, 1, 2, 3),
                fps: float = 5.0) -> tuple[CellScene, tuple[CornerVisit, ...]]:
    """The scene and its corner visits (``visits``: indices into ``zone_corners``, in walking
    order). ``hidden_corner``: with the cabinet that hides the far-left corner."""
    path: list[tuple[float, float, float]] = []
    poses, done = [], []
    t = 0.0
    for cx, cy in (zone_corners()[k] for k in visits):
        sx, sy = (1 if cx > 0 else -1), (1 if cy > 0 else -1)
        out = (cx + sx * OUTSIDE_M, cy + sy * OUTSIDE_M)
        crouch = (cx - sx * CORNER_INSET_M, cy - sy * CORNER_INSET_M)
        if path:  # walk on from the last corner's outside point
            last = path[-1][1:]
            t += max(abs(out[0] - last[0]), abs(out[1] - last[1])) / WALK_MPS
        path.append((t, *out))
        t += STEP_S
        path.append((t, *crouch))
        poses.append((t + 0.01, t + CROUCH_S, "crouching"))
        done.append(CornerVisit((cx, cy), crouch, (t + 0.01, t + CROUCH_S)))
        t += CROUCH_S + 0.2  # stands up, then steps out
        path.append((t, *crouch))
        t += STEP_S
        path.append((t, *out))
    walker = Walker(tuple(path), poses=tuple(poses))
    scene = CellScene((walker,), blocks=(CABINET,) if hidden_corner else (), fps=fps,
                      duration_s=t + 0.4)
    return scene, tuple(done)


APPEAR_S = 1.6  # after the monitor's start-up STOP (clear_time) has ended


def late_detection_walk(fps: float = 5.0) -> tuple[CellScene, frozenset[int]]:
    """A person steps into view inside the protective zone at ``APPEAR_S`` (from nowhere the
    camera saw: no earlier detection, no lost-person hold) and walks out towards the camera;
    the detector misses their first frame (the frame is written without them). The scene and
    the missed frame's index: the ground truth has them inside one frame before any
    detection."""
    walker = Walker(((APPEAR_S, 0.4, -0.4), (APPEAR_S + 0.4, 0.4, -0.4), (APPEAR_S + 2.0, 0.4,
                                                                         -2.4)),
                    appear_s=APPEAR_S)
    scene = CellScene((walker,), fps=fps, duration_s=APPEAR_S + 2.4)
    return scene, frozenset({round(APPEAR_S * fps)})


def walk_zone_data(scene: CellScene) -> dict:
    """The scene's zone file (as data). Floor no camera sees is accepted (``unobserved_ok``)
    so that the walk can show it as a blind spot."""
    return Scenario("corner-walk", "commissioning walk", scene, unobserved_ok=True).zone_data()


def write_walk_scene(folder: Path, scene: CellScene, missed: frozenset[int] = frozenset()
                     ) -> tuple[CellFrameTruth, ...]:
    """Render the scene into FOLDER: walk.mp4, cell.yaml (its zones), truth.json (where the
    person was in each frame); the truth of every frame. ``missed``: frames written as the
    empty cell (a detector that misses them; the truth keeps the persons there)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    empty = scene.background()

    def frames():
        for image, truth in scene.frames():
            yield (empty if truth.index in missed else image), truth
    truths = tuple(write_video(folder / VIDEO_FILE, frames(), scene.fps))
    write_cell_data(walk_zone_data(scene), folder / ZONES_FILE)
    write_truth(folder / TRUTH_FILE, truth_of(truths), scene.fps)
    return truths
