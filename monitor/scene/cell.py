"""Cell scenes in perspective: several persons, fixtures that hide them, cut-outs, ground truth.

A ``CellScene`` is a calibrated camera looking into a robot cell (metres, z up, origin at the
robot base on the floor) with

* ``Walker``s: persons following a floor path (standing, walking, running with a matching
  stride, crouching or kneeling, each with its own height);
* ``Block``s: fixtures as cell volumes (benches, crates, cabinets, the robot base) drawn as
  shaded boxes in perspective; every block is also an ``occluder`` of the scene's zone file;
* ``CutOut``s: static person-coloured cardboard figures (what a mask zone is for);
* ``Platform``s: raised floor regions persons stand on (a walker's ``floor_z_m``), drawn into
  the background and declared in the scene's zone file under ``floors:``.

Everything is drawn in painter's order (farthest first, by the camera depth of each item's
floor point nearest to the camera), so a bench in front of a person hides the legs.
The ground truth keeps every person of the scene in every frame, hidden or not: true floor
position, height, posture, visible fraction and visible box (None when wholly hidden).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from monitor.scene import (
    WORKWEAR_BGR,
    Camera,
    Figure,
    add_noise,
    box_of,
    draw_figure,
    draw_robot,
    limb,
    path_position,
    render_background,
)

# the scenes' robot is painted into the background and hides nobody (persons are drawn over
# it, some stand where the default 0.5 m base would be): a token base says so
SCENE_ROBOT_BASE = {"radius_m": 0.1, "height_m": 0.1}
POSTURE_HEIGHT = {"standing": 1.0, "kneeling": 0.72, "crouching": 0.58}  # of standing height
SCENE_CAMERA = Camera.look_at(
    "cam0", (640, 360), np.array([[450.0, 0, 320], [0, 450.0, 180], [0, 0, 1]]),
    position_m=(0.0, -6.0, 3.2), target_m=(0.0, 0.0, 0.8))


@dataclass(frozen=True)
class Walker:
    """A person: ``path`` of (time s, x m, y m) points, linear in between, held at the ends;
    ``height_m`` standing height; ``posture`` standing / kneeling / crouching (the figure's
    height is the standing height times ``POSTURE_HEIGHT``); ``running`` doubles the stride.
    ``appear_s``/``leave_s`` bound when the person is in the scene. ``poses``: (from s, to s,
    posture) spans in which the person takes another posture (a walker who crouches at the
    corners of a zone); ``posture`` holds outside them."""

    path: tuple[tuple[float, float, float], ...]
    height_m: float = 1.75
    posture: str = "standing"
    running: bool = False
    appear_s: float = 0.0
    leave_s: float = math.inf
    floor_z_m: float = 0.0  # the surface the person stands on (a platform's height)
    poses: tuple[tuple[float, float, str], ...] = ()
    # frame indices in which a detector misses this person (a real detector's flicker): the
    # figure is not drawn there, the ground truth keeps the person as if drawn
    unseen_frames: frozenset[int] = frozenset()

    def position_at(self, t: float) -> tuple[float, float]:
        return path_position(self.path, t)

    def speed_at(self, t: float) -> float:
        a, b = self.position_at(max(0.0, t - 0.05)), self.position_at(t + 0.05)
        return math.hypot(b[0] - a[0], b[1] - a[1]) / 0.1

    @property
    def figure_height_m(self) -> float:
        return self.height_m * POSTURE_HEIGHT[self.posture]

    def posture_at(self, t: float) -> str:
        return next((p for t0, t1, p in self.poses if t0 <= t <= t1), self.posture)

    def figure_height_at(self, t: float) -> float:
        return self.height_m * POSTURE_HEIGHT[self.posture_at(t)]


@dataclass(frozen=True)
class Block:
    """A fixture: axis-aligned box from ``min_m`` to ``max_m`` (metres), drawn in ``colour``
    (BGR, never work wear); ``occluder`` puts it in the zone file as an occluder."""

    zone_id: str
    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]
    colour: tuple[int, int, int] = (70, 95, 115)
    occluder: bool = True
    # put into the cell after the commissioning reference was taken: not in ``reference()``
    after_reference: bool = False


@dataclass(frozen=True)
class Platform:
    """A raised floor region: the floor rectangle ``min_m`` .. ``max_m`` (x, y, metres) at
    ``height_m``, a solid block under it, drawn in ``colour`` (BGR, never work wear)."""

    floor_id: str
    min_m: tuple[float, float]
    max_m: tuple[float, float]
    height_m: float
    colour: tuple[int, int, int] = (95, 115, 120)

    @property
    def block(self) -> Block:
        return Block(self.floor_id, (*self.min_m, 0.0), (*self.max_m, self.height_m),
                     self.colour, occluder=False)


@dataclass(frozen=True)
class CutOut:
    """A static person-coloured cardboard figure standing at ``floor_m``."""

    floor_m: tuple[float, float]
    height_m: float = 1.7


@dataclass(frozen=True)
class PersonState:
    """Ground truth of one person in one frame, seen or not."""

    person_id: int
    floor_m: tuple[float, float]
    height_m: float  # figure height now (posture included)
    posture: str
    visible_fraction: float
    box_px: tuple[int, int, int, int] | None  # visible pixels, x2/y2 exclusive
    full_box_px: tuple[int, int, int, int] | None  # whole figure, even where hidden


@dataclass(frozen=True)
class CellFrameTruth:
    index: int
    time_s: float
    persons: tuple[PersonState, ...]


@dataclass(frozen=True)
class CellScene:
    walkers: tuple[Walker, ...]
    blocks: tuple[Block, ...] = ()
    cutouts: tuple[CutOut, ...] = ()
    camera: Camera = SCENE_CAMERA
    fps: float = 10.0
    duration_s: float = 6.0
    seed: int = 0
    robot: bool = True
    noise: bool = True
    extra: dict = field(default_factory=dict, compare=False)
    platforms: tuple[Platform, ...] = ()  # drawn under everything else (persons stand on them)

    @property
    def n_frames(self) -> int:
        return round(self.duration_s * self.fps)

    def background(self) -> np.ndarray:
        cam = self.camera
        img = render_background(cam.width, cam.height, np.random.default_rng(self.seed))
        for p in self.platforms:
            _draw_block(img, cam, p.block)
        if self.robot:
            base = cam.project(np.array([[0.0, 0.0, 0.9]]))[0]
            draw_robot(img, (int(base[0]), int(base[1])), cam.height / 720 * 1.4, 0.3)
        return img

    def reference(self) -> np.ndarray:
        """The commissioning reference: the empty cell with its fixtures and cut-outs (no
        persons, no noise), as ``monitor reference capture`` takes it."""
        before = replace(self, blocks=tuple(b for b in self.blocks if not b.after_reference))
        img, _ = before.render(before.background(), -1, -math.inf)
        return img

    def frames(self) -> Iterator[tuple[np.ndarray, CellFrameTruth]]:
        rng = np.random.default_rng(self.seed + 1)
        static = self.background()
        for index in range(self.n_frames):
            t = index / self.fps
            img, truth = self.render(static, index, t)
            yield (add_noise(img, rng) if self.noise else img), truth

    def render(self, static: np.ndarray, index: int, t: float
               ) -> tuple[np.ndarray, CellFrameTruth]:
        cam = self.camera
        img = static.copy()
        shape = img.shape[:2]
        owner = np.full(shape, -1, np.int16)
        items: list[tuple[float, str, int]] = []
        present = [k for k, w in enumerate(self.walkers) if w.appear_s <= t <= w.leave_s]
        for k in present:
            x, y = self.walkers[k].position_at(t)
            items.append((_depth(cam, np.array([[x, y, 0.0]])), "walker", k))
        for k, b in enumerate(self.blocks):
            items.append((_depth(cam, _block_corners(b)[:4]), "block", k))
        for k, c in enumerate(self.cutouts):
            items.append((_depth(cam, np.array([[*c.floor_m, 0.0]])), "cutout", k))
        figures: dict[int, Figure] = {}
        for _, kind, k in sorted(items, key=lambda it: -it[0]):
            if kind == "walker":
                fig = self._figure(k, t)
                if fig is None:
                    continue
                figures[k] = fig
                mask = np.zeros(shape, np.uint8)
                posture = self.walkers[k].posture_at(t)
                draw_posed(mask, fig, posture, colours=((255,),) * 4)
                if index not in self.walkers[k].unseen_frames:
                    draw_posed(img, fig, posture)
                owner[mask > 0] = k
            elif kind == "block":
                drawn = _draw_block(img, cam, self.blocks[k])
                owner[drawn] = -1
            else:
                c = self.cutouts[k]
                feet, head = cam.project(np.array([[*c.floor_m, 0.0], [*c.floor_m, c.height_m]]))
                fig = Figure((float(feet[0]), float(feet[1])), float(feet[1] - head[1]),
                             arm_raise=0.3)
                mask = np.zeros(shape, np.uint8)
                draw_figure(mask, Figure(fig.feet_px, fig.height_px, arm_raise=0.3,
                                         colours=((255,),) * 4))
                draw_figure(img, fig)
                owner[mask > 0] = -2  # person-coloured, but nobody
        persons = []
        for k in present:
            w = self.walkers[k]
            posture = w.posture_at(t)
            x, y = w.position_at(t)
            fig = figures.get(k)
            full = None
            box = None
            frac = 0.0
            if fig is not None:
                mask = np.zeros(shape, np.uint8)
                draw_posed(mask, fig, posture, colours=((255,),) * 4)
                whole = mask > 0
                full = box_of(whole)
                vis = owner == k
                box = box_of(vis)
                frac = float(vis.sum()) / max(1, int(whole.sum()))
            persons.append(PersonState(k, (float(x), float(y)), w.figure_height_at(t), posture,
                                       frac, box, full))
        return img, CellFrameTruth(index, t, tuple(persons))

    def _figure(self, k: int, t: float) -> Figure | None:
        w = self.walkers[k]
        cam = self.camera
        x, y = w.position_at(t)
        z = w.floor_z_m
        feet, head = cam.project(np.array([[x, y, z], [x, y, z + w.figure_height_at(t)]]))
        height_px = float(feet[1] - head[1])
        if height_px <= 2:
            return None
        speed = w.speed_at(t)
        moving = speed > 0.05 and w.posture_at(t) == "standing"
        # one stride cycle per 1.4 m walking, 2.2 m running; a longer swing when running
        cycle = 2.2 if w.running else 1.4
        travelled = _distance_along(w, t)
        stride = (0.75 if w.running else 0.45) if moving else 0.0
        return Figure((float(feet[0]), float(feet[1])), height_px,
                      phase=travelled / cycle * 2 * math.pi if moving else 0.0, stride=stride)


def _distance_along(w: Walker, t: float) -> float:
    total = 0.0
    for (t0, x0, y0), (t1, x1, y1) in itertools.pairwise(w.path):
        if t <= t0:
            break
        a = min(1.0, (t - t0) / max(t1 - t0, 1e-9))
        total += a * math.hypot(x1 - x0, y1 - y0)
    return total


def _depth(cam: Camera, points_m: np.ndarray) -> float:
    """Smallest camera depth (metres along the optical axis) of some cell points."""
    return float((points_m @ cam.rotation.T + cam.translation)[:, 2].min())


def _block_corners(b: Block) -> np.ndarray:
    (x0, y0, z0), (x1, y1, z1) = b.min_m, b.max_m
    return np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                     [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], float)


def _draw_block(img: np.ndarray, cam: Camera, b: Block) -> np.ndarray:
    """Draw a shaded box; return the mask of the pixels it covers."""
    px = cam.project(_block_corners(b))
    hull = cv2.convexHull(np.round(px).astype(np.int32))
    mask = np.zeros(img.shape[:2], np.uint8)
    cv2.fillConvexPoly(mask, hull, 1, cv2.LINE_8)
    cv2.fillConvexPoly(img, hull, b.colour, cv2.LINE_8)
    top = np.round(px[4:]).astype(np.int32)
    lighter = tuple(min(255, int(c * 1.35) + 10) for c in b.colour)
    cv2.fillConvexPoly(img, cv2.convexHull(top), lighter, cv2.LINE_8)
    cv2.polylines(img, [hull], True, (40, 40, 40), 1, cv2.LINE_8)
    return mask > 0


def draw_posed(canvas: np.ndarray, fig: Figure, posture: str = "standing",
               colours: tuple[tuple[int, ...], ...] | None = None) -> None:
    """Draw a figure standing (``draw_figure``), kneeling or crouching; ``fig.height_px`` is the
    height of the posed figure, soles (or knees) to the top of the head."""
    if colours is not None:
        fig = Figure(fig.feet_px, fig.height_px, fig.phase, fig.arm_raise, colours, fig.stride)
    if posture == "standing":
        draw_figure(canvas, fig)
        return
    full = fig.height_px / POSTURE_HEIGHT[posture]  # the same person standing
    fx, fy = fig.feet_px
    c = fig.colours
    hip_y = fy - (fig.height_px - 0.5 * full)
    # upper body as when standing, moved down onto the hip
    shoulder_y = hip_y - 0.30 * full
    for side in (-1, 1):
        hip = np.array([fx + side * 0.05 * full, hip_y])
        if posture == "crouching":  # knees out and up, feet under the hips
            knee = np.array([fx + side * 0.2 * full, hip_y - 0.05 * full])
            foot = np.array([fx + side * 0.12 * full, fy - 0.02 * full])
        else:  # kneeling: thighs down to the knee on the floor, shins back
            knee = np.array([fx + side * 0.06 * full, fy - 0.04 * full])
            foot = np.array([fx + side * 0.06 * full + 0.2 * full, fy - 0.03 * full])
        limb(canvas, hip, knee, 0.10 * full, c[1])
        limb(canvas, knee, foot, 0.09 * full, c[1])
    for side in (-1, 1):
        sh = np.array([fx + side * 0.11 * full, shoulder_y])
        hand = sh + 0.36 * full * np.array([math.sin(side * 0.5), math.cos(side * 0.5)])
        limb(canvas, sh, hand, 0.075 * full, c[2])
    top = shoulder_y - 0.02 * full
    torso = np.array([[fx - 0.13 * full, top], [fx + 0.13 * full, top],
                      [fx + 0.10 * full, hip_y + 0.03 * full],
                      [fx - 0.10 * full, hip_y + 0.03 * full]])
    cv2.fillConvexPoly(canvas, np.round(torso).astype(np.int32), c[0], cv2.LINE_8)
    limb(canvas, np.array([fx, shoulder_y - 0.02 * full]),
          np.array([fx, shoulder_y - 0.06 * full]), 0.07 * full, c[0])
    head_r = max(2, round(0.065 * full))
    cv2.circle(canvas, (round(fx), round(shoulder_y - 0.13 * full)), head_r, c[3], -1,
               cv2.LINE_8)


def camera_calibration(cam: Camera) -> dict:
    """The zone-file ``calibration`` of a scene camera (pinhole, exact)."""
    return {"type": "pinhole", "camera_matrix": cam.K.tolist(), "distortion": [],
            "rotation": cam.rotation.tolist(), "translation_m": cam.translation.tolist()}


def zone_data(scene: CellScene, protective: tuple[tuple[float, float], tuple[float, float]]
              = ((-1.0, -1.0), (1.0, 1.0)), warning_half_m: float = 2.5) -> dict:
    """A zone file (as data) for a scene: its camera, a protective box around the robot, a
    warning square, and every occluding block as an ``occluder`` (the default robot base; the
    scenario suite declares ``SCENE_ROBOT_BASE``)."""
    cam = scene.camera
    (x0, y0), (x1, y1) = protective
    zones = [
        {"id": "robot-protective", "kind": "protective", "shape": "box",
         "min_m": [x0, y0, 0.0], "max_m": [x1, y1, 2.2]},
        {"id": "robot-warning", "kind": "warning", "speed_scale": 0.3, "shape": "extrude",
         "points_m": [[-warning_half_m, -warning_half_m], [warning_half_m, -warning_half_m],
                      [warning_half_m, warning_half_m], [-warning_half_m, warning_half_m]],
         "z_min_m": 0.0, "z_max_m": 2.2},
    ]
    zones += [{"id": b.zone_id, "kind": "occluder", "shape": "box", "min_m": list(b.min_m),
               "max_m": list(b.max_m)} for b in scene.blocks if b.occluder]
    data = {"version": 1, "name": "scenario",
            "cameras": [{"id": cam.camera_id, "width": cam.width, "height": cam.height,
                         "calibration": camera_calibration(cam)}],
            "zones": zones}
    if scene.platforms:
        data["floors"] = [{"id": p.floor_id, "height_m": p.height_m, "points_m": [
            [p.min_m[0], p.min_m[1]], [p.max_m[0], p.min_m[1]], [p.max_m[0], p.max_m[1]],
            [p.min_m[0], p.max_m[1]]]} for p in scene.platforms]
    return data


__all__ = [
    "SCENE_CAMERA",
    "SCENE_ROBOT_BASE",
    "WORKWEAR_BGR",
    "Block",
    "CellFrameTruth",
    "CellScene",
    "CutOut",
    "PersonState",
    "Platform",
    "Walker",
    "camera_calibration",
    "draw_posed",
    "zone_data",
]
