"""Synthetic robot-cell scenes with ground truth: the embedded default input of the monitor.

Persons wear saturated magenta work wear (hood, jacket, trousers): the colour the synthetic
model detects (see models/README.md). Everything else in the cell is drawn in colours the model
must ignore: grey floor and walls, an orange robot, yellow fixtures, and distractors (red, blue,
pink, white and orange mannequins, a magenta sticker smaller than the smallest person).

Two kinds of scenes:
- ``random_frames`` for detector accuracy: independent frames with 0..N persons of varied size,
  pose and position, some near the frame edges, some partly hidden behind a crate.
- ``DemoScene``: one camera ``cam0`` (1280x720) calibrated in the cell frame (metres, z up,
  origin at the robot base), a person walking from outside the view through the warning zone into
  the protective zone and out again.

Everything is deterministic from a seed. Ground-truth person boxes are the boxes of the
person's *visible* pixels, ``x1, y1, x2, y2`` with exclusive right/bottom edges (pixel i covers
[i, i+1)).

Also here: detector accuracy against a scene's ground truth (``accuracy.py``). May import: the
bottom layer only (``errors``, ``progress``); the frames and the detector's self-test draw from it.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from monitor.errors import InputError

# Work-wear colours, BGR. Each has R + B - 2G >= 1.55 (of 255), the model's person test.
WORKWEAR_BGR = ((235, 25, 235), (215, 12, 215), (245, 40, 245), (225, 20, 205))
# Distractor colours, BGR: far below the person test (red, blue, pink, white, orange, purple-grey).
DISTRACTOR_BGR = ((30, 30, 220), (220, 40, 30), (203, 192, 255), (235, 235, 235), (0, 140, 255),
                  (150, 110, 150))
PERSON_HEIGHT_M = 1.75


@dataclass(frozen=True)
class Camera:
    """Pinhole camera in the cell frame (OpenCV convention: x right, y down, z forward).

    ``rotation`` and ``translation`` map cell points to camera points: p_cam = R p_cell + t.
    """

    camera_id: str
    width: int
    height: int
    K: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))

    @classmethod
    def look_at(cls, camera_id: str, size: tuple[int, int], K: np.ndarray,
                position_m: tuple[float, float, float], target_m: tuple[float, float, float],
                up: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> Camera:
        pos = np.asarray(position_m, float)
        forward = np.asarray(target_m, float) - pos
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, np.asarray(up, float))
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        rotation = np.stack([right, down, forward])  # rows: camera axes in cell coordinates
        return cls(camera_id, size[0], size[1], np.asarray(K, float), rotation, -rotation @ pos)

    def project(self, points_m: np.ndarray) -> np.ndarray:
        """Cell points (N, 3) in metres to pixels (N, 2)."""
        cam = np.asarray(points_m, float).reshape(-1, 3) @ self.rotation.T + self.translation
        uv = cam[:, :2] / cam[:, 2:3]
        return uv @ self.K[:2, :2].T + self.K[:2, 2]


DEMO_CAMERA = Camera.look_at(
    "cam0", (1280, 720), np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]]),
    position_m=(0.0, -6.0, 3.2), target_m=(0.0, 0.0, 0.8))


@dataclass(frozen=True)
class Figure:
    """A standing or walking figure drawn in image space.

    ``feet_px`` is the bottom centre, ``height_px`` the height from soles to top of head,
    ``phase`` the walking cycle in radians, ``arm_raise`` extra shoulder angle in radians.
    """

    feet_px: tuple[float, float]
    height_px: float
    phase: float = 0.0
    arm_raise: float = 0.0
    colours: tuple[tuple[int, int, int], ...] = WORKWEAR_BGR
    stride: float = 0.45  # leg swing amplitude, radians


@dataclass(frozen=True)
class PersonTruth:
    box_px: tuple[int, int, int, int]  # visible pixels, x2/y2 exclusive
    full_box_px: tuple[int, int, int, int]  # whole figure, even where hidden or outside
    visible_fraction: float
    floor_m: tuple[float, float] | None = None  # position on the floor (demo scene only)


@dataclass(frozen=True)
class FrameTruth:
    index: int
    time_s: float
    persons: tuple[PersonTruth, ...]
    distractor_boxes_px: tuple[tuple[int, int, int, int], ...] = ()


def limb(canvas: np.ndarray, a: np.ndarray, b: np.ndarray, thickness: float,
          colour: tuple[int, int, int]) -> None:
    t = max(2, round(thickness))
    cv2.line(canvas, _pt(a), _pt(b), colour, t, cv2.LINE_8)
    for p in (a, b):  # round caps
        cv2.circle(canvas, _pt(p), max(1, t // 2), colour, -1, cv2.LINE_8)


def _pt(p: np.ndarray) -> tuple[int, int]:
    return round(float(p[0])), round(float(p[1]))


def draw_figure(canvas: np.ndarray, fig: Figure) -> None:
    """Draw a full-body figure (head, torso, arms, legs) in place."""
    h = fig.height_px
    fx, fy = fig.feet_px
    c = fig.colours
    hip = np.array([fx, fy - 0.50 * h])
    shoulder_y = fy - 0.80 * h
    leg_len, arm_len = 0.47 * h, 0.36 * h
    swing = math.sin(fig.phase) * fig.stride
    for side, sgn in ((-1, 1), (1, -1)):
        hip_s = hip + np.array([side * 0.05 * h, 0])
        ang = sgn * swing
        foot = hip_s + leg_len * np.array([math.sin(ang), math.cos(ang)])
        limb(canvas, hip_s, foot, 0.10 * h, c[1])
    for side, sgn in ((-1, -1), (1, 1)):
        sh = np.array([fx + side * 0.11 * h, shoulder_y])
        ang = sgn * swing * 0.8 + side * (0.15 + fig.arm_raise)
        hand = sh + arm_len * np.array([math.sin(ang), math.cos(ang)])
        limb(canvas, sh, hand, 0.075 * h, c[2])
    top = shoulder_y - 0.02 * h
    torso = np.array([[fx - 0.13 * h, top], [fx + 0.13 * h, top],
                      [fx + 0.10 * h, fy - 0.47 * h], [fx - 0.10 * h, fy - 0.47 * h]])
    cv2.fillConvexPoly(canvas, np.round(torso).astype(np.int32), c[0], cv2.LINE_8)
    limb(canvas, np.array([fx, shoulder_y - 0.02 * h]), np.array([fx, fy - 0.86 * h]),
          0.07 * h, c[0])  # neck
    head_r = max(2, round(0.065 * h))
    cv2.circle(canvas, (round(fx), round(fy - 0.93 * h)), head_r, c[3], -1, cv2.LINE_8)


def _figure_mask(shape: tuple[int, int], fig: Figure) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    draw_figure(mask, Figure(fig.feet_px, fig.height_px, fig.phase, fig.arm_raise,
                             ((255,),) * 4, fig.stride))
    return mask > 0


def box_of(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    ys = np.flatnonzero(mask.any(axis=1))
    if len(ys) == 0:
        return None
    xs = np.flatnonzero(mask.any(axis=0))
    return int(xs[0]), int(ys[0]), int(xs[-1]) + 1, int(ys[-1]) + 1


def _figure_extent(fig: Figure) -> tuple[float, float, float, float]:
    """Generous bounding box of a figure, for placement."""
    h = fig.height_px
    return fig.feet_px[0] - 0.5 * h, fig.feet_px[1] - h - 2, fig.feet_px[0] + 0.5 * h, \
        fig.feet_px[1] + 0.06 * h + 2


def render_background(width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """Floor, back wall, shelves and an orange robot; no persons, no noise."""
    img = np.empty((height, width, 3), np.uint8)
    horizon = int(height * 0.38)
    wall = np.linspace(150, 170, horizon)[:, None]
    img[:horizon] = np.repeat(wall, width, axis=1)[..., None].astype(np.uint8)
    floor = np.linspace(105, 135, height - horizon)[:, None]
    img[horizon:] = np.repeat(floor, width, axis=1)[..., None].astype(np.uint8)
    # floor markings: yellow/black hazard lines
    y_line = int(height * 0.83)
    for x in range(0, width, 60):
        cv2.rectangle(img, (x, y_line), (x + 30, y_line + 8), (0, 210, 240), -1)
    # shelves on the back wall with boxes of distractor colours
    for k in range(3):
        x0 = int(width * (0.05 + 0.32 * k + rng.uniform(0, 0.05)))
        y0 = int(height * 0.12)
        cv2.rectangle(img, (x0, y0), (x0 + int(width * 0.16), y0 + 6), (90, 90, 90), -1)
        for j in range(3):
            col = DISTRACTOR_BGR[int(rng.integers(len(DISTRACTOR_BGR)))]
            bx = x0 + 8 + j * int(width * 0.05)
            cv2.rectangle(img, (bx, y0 - int(height * 0.05)), (bx + int(width * 0.035), y0),
                          col, -1)
    return img


def draw_robot(img: np.ndarray, base_px: tuple[int, int], scale: float, angle: float) -> None:
    """An orange 3-link arm on a grey pedestal (colours the model ignores)."""
    bx, by = base_px
    cv2.rectangle(img, (int(bx - 40 * scale), int(by - 60 * scale)),
                  (int(bx + 40 * scale), by), (80, 80, 80), -1)
    j1 = np.array([bx, by - 60 * scale])
    j2 = j1 + 150 * scale * np.array([math.sin(angle), -math.cos(angle)])
    j3 = j2 + 120 * scale * np.array([math.cos(angle * 0.7), math.sin(angle * 0.7) * 0.5])
    for a, b, t in ((j1, j2, 34), (j2, j3, 26)):
        cv2.line(img, _pt(a), _pt(b), (0, 120, 255), max(2, int(t * scale)), cv2.LINE_AA)
        cv2.circle(img, _pt(a), max(2, int(t * 0.7 * scale)), (40, 40, 40), -1)
    cv2.circle(img, _pt(j3), max(2, int(12 * scale)), (60, 60, 60), -1)


def add_noise(img: np.ndarray, rng: np.random.Generator, sigma: float = 2.0) -> np.ndarray:
    """Sensor noise, generated at quarter resolution (cheap) and shared by the channels: whole
    grey steps added with saturation (a BGR uint8 image; 4x faster than float arithmetic at
    1280x720, and the same pixels)."""
    noise = rng.normal(0.0, sigma, size=(img.shape[0] // 4 + 1, img.shape[1] // 4 + 1))
    steps = np.rint(noise.astype(np.float32)).astype(np.int16)
    steps = cv2.resize(cv2.merge([steps] * img.shape[2]), (img.shape[1], img.shape[0]),
                       interpolation=cv2.INTER_NEAREST)
    return cv2.add(img, steps, dtype=cv2.CV_8U)


def _compose(background: np.ndarray, figures: list[Figure],
             occluders: list[tuple[tuple[int, int, int, int], tuple[int, int, int]]],
             ) -> tuple[np.ndarray, list[tuple[np.ndarray, Figure]]]:
    """Draw figures (far first) then the foreground occluders; return the visible masks."""
    img = background.copy()
    owner = np.full(img.shape[:2], -1, np.int16)
    order = sorted(range(len(figures)), key=lambda i: figures[i].feet_px[1])
    for i in order:
        mask = _figure_mask(img.shape[:2], figures[i])
        draw_figure(img, figures[i])
        owner[mask] = i
    for (x1, y1, x2, y2), colour in occluders:
        cv2.rectangle(img, (x1, y1), (x2 - 1, y2 - 1), colour, -1)
        cv2.rectangle(img, (x1, y1), (x2 - 1, y1 + 4), (40, 40, 40), -1)
        owner[max(y1, 0):max(y2, 0), max(x1, 0):max(x2, 0)] = -1
    return img, [(owner == i, figures[i]) for i in range(len(figures))]


def _truth(visible: list[tuple[np.ndarray, Figure]], shape: tuple[int, int],
           floor: list[tuple[float, float] | None] | None = None) -> tuple[PersonTruth, ...]:
    out = []
    for k, (mask, fig) in enumerate(visible):
        box = box_of(mask)
        if box is None:
            continue
        full = _figure_mask(shape, fig)
        full_box = box_of(full) or box
        total = max(1, int(full.sum()))
        out.append(PersonTruth(box, full_box, float(mask.sum()) / total,
                               floor[k] if floor else None))
    return tuple(out)


def random_frames(n: int, seed: int = 0, size: tuple[int, int] = (1280, 720),
                  max_persons: int = 4, min_height: float = 0.2, max_height: float = 0.8,
                  min_gap_px: float = 110.0) -> Iterator[tuple[np.ndarray, FrameTruth]]:
    """Independent frames for detector accuracy tests, with ground truth.

    Persons are ``min_height``..``max_height`` of the frame height tall and stand at least
    ``min_gap_px`` apart (edge to edge), some near the frame edges, some with their legs hidden
    behind a crate. Each frame also holds distractors: mannequins in other colours and a small
    magenta sticker (``FrameTruth.distractor_boxes_px``).
    """
    width, height = size
    rng = np.random.default_rng(seed)
    for index in range(n):
        background = render_background(width, height, rng)
        draw_robot(background, (int(width * rng.uniform(0.3, 0.7)), int(height * 0.7)),
                   height / 720, rng.uniform(-0.8, 0.8))
        figures: list[Figure] = []
        taken: list[tuple[float, float, float, float]] = []
        distractors: list[tuple[int, int, int, int]] = []
        n_persons = int(rng.integers(0, max_persons + 1))
        tries = 0
        while len(figures) < n_persons + 2 and tries < 200:
            tries += 1
            h = rng.uniform(min_height, max_height) * height
            if rng.random() < 0.25:  # near a frame edge
                inset = rng.uniform(0.1 * h, 0.3 * h)
                fx = inset if rng.random() < 0.5 else width - inset
            else:
                fx = rng.uniform(0.3 * h, width - 0.3 * h)
            fy = rng.uniform(h + 4, height - 0.02 * height)
            distractor = len(figures) >= n_persons
            colours = WORKWEAR_BGR if not distractor else \
                (DISTRACTOR_BGR[int(rng.integers(len(DISTRACTOR_BGR)))],) * 4
            fig = Figure((float(fx), float(fy)), float(h), float(rng.uniform(0, 2 * math.pi)),
                         float(rng.uniform(-0.2, 0.9)), colours, float(rng.uniform(0.0, 0.5)))
            ext = _figure_extent(fig)
            gap = min_gap_px
            if any(not (ext[2] + gap < t[0] or t[2] + gap < ext[0] or ext[3] + gap < t[1]
                        or t[3] + gap < ext[1]) for t in taken):
                continue
            taken.append(ext)
            figures.append(fig)
        persons = [f for f in figures if f.colours == WORKWEAR_BGR]
        mannequins = [f for f in figures if f.colours != WORKWEAR_BGR]
        occluders = []
        for fig in persons:
            if rng.random() < 0.3:  # a crate hides the legs (up to 40 % of the height)
                h = fig.height_px
                top = int(fig.feet_px[1] - rng.uniform(0.15, 0.4) * h)
                x1 = int(fig.feet_px[0] - rng.uniform(0.3, 0.5) * h)
                x2 = int(fig.feet_px[0] + rng.uniform(0.3, 0.5) * h)
                occluders.append(((x1, top, x2, int(fig.feet_px[1] + 0.08 * h) + 2),
                                  (70, 95, 115)))
        img, visible = _compose(background, persons + mannequins, occluders)
        # the small magenta sticker: far below the smallest person's size, and at least four
        # cells of the model's 26x26 grid away from any figure (closer, it joins that figure)
        sticker = int(rng.integers(6, 12)) * height // 720
        away = 64 / min(416 / width, 416 / height)
        for _ in range(50):
            sx, sy = int(rng.integers(0, width - sticker)), int(rng.integers(0, height - sticker))
            box = (sx - away, sy - away, sx + sticker + away, sy + sticker + away)
            if all(box[2] < t[0] or t[2] < box[0] or box[3] < t[1] or t[3] < box[1]
                   for t in taken):
                cv2.rectangle(img, (sx, sy), (sx + sticker - 1, sy + sticker - 1),
                              WORKWEAR_BGR[0], -1)
                distractors.append((sx, sy, sx + sticker, sy + sticker))
                break
        for mask, _fig in visible[len(persons):]:
            box = box_of(mask)
            if box:
                distractors.append(box)
        truth = FrameTruth(index, 0.0, _truth(visible[:len(persons)], img.shape[:2]),
                           tuple(distractors))
        yield add_noise(img, rng), truth



def path_position(path, t: float) -> tuple[float, float]:
    """Floor position (metres) at time ``t`` on a walk of (time, x, y) waypoints, linearly
    interpolated; the first point before it starts, the last after it ends."""
    if t <= path[0][0]:
        return path[0][1], path[0][2]
    for (t0, x0, y0), (t1, x1, y1) in itertools.pairwise(path):
        if t <= t1:
            a = (t - t0) / max(t1 - t0, 1e-9)
            return x0 + a * (x1 - x0), y0 + a * (y1 - y0)
    return path[-1][1], path[-1][2]

@dataclass(frozen=True)
class DemoScene:
    """A person walks from outside the view, through the warning zone, into the protective zone
    (around the robot base) and out again. Camera ``DEMO_CAMERA`` (cam0, 1280x720, 15 fps)."""

    seed: int = 0
    fps: float = 15.0
    duration_s: float = 24.0
    camera: Camera = DEMO_CAMERA
    # (time s, x m, y m): the walking path in the cell frame; the person pauses inside.
    path: tuple[tuple[float, float, float], ...] = (
        (0.0, -5.5, -1.6), (7.0, -0.4, -0.6), (10.0, -0.4, -0.6), (17.0, 5.5, -2.2),
        (24.0, 5.5, -2.2))
    loop: bool = False  # loop the walk (long scenes for soak and health tests)

    @property
    def n_frames(self) -> int:
        return round(self.duration_s * self.fps)

    def position_at(self, t: float) -> tuple[float, float]:
        cycle = self.path[-1][0]
        if self.loop:
            t = t % cycle
        return path_position(self.path, t)

    def figure_at(self, t: float) -> Figure | None:
        x, y = self.position_at(t)
        cam = self.camera
        feet, head = cam.project(np.array([[x, y, 0.0], [x, y, PERSON_HEIGHT_M]]))
        height_px = float(feet[1] - head[1])
        if feet[0] < -0.5 * height_px or feet[0] > cam.width + 0.5 * height_px:
            return None
        x_prev, y_prev = self.position_at(max(0.0, t - 0.05))
        moving = math.hypot(x - x_prev, y - y_prev) > 1e-6
        # 1.4 m per stride cycle
        travelled = t * 1.2
        return Figure((float(feet[0]), float(feet[1])), height_px,
                      phase=travelled / 1.4 * 2 * math.pi if moving else 0.0,
                      stride=0.45 if moving else 0.0)

    def background(self) -> np.ndarray:
        rng = np.random.default_rng(self.seed)
        cam = self.camera
        img = render_background(cam.width, cam.height, rng)
        # the poster in the mask zone: a blue figure (not work wear)
        cv2.rectangle(img, (40, 80), (140, 260), (230, 230, 230), -1)
        draw_figure(img, Figure((90.0, 250.0), 160.0, colours=(DISTRACTOR_BGR[1],) * 4))
        # the shelf of the watch zone
        cv2.rectangle(img, (1000, 120), (1200, 300), (95, 105, 110), -1)
        for k, col in enumerate(((0, 140, 255), (30, 30, 220), (220, 40, 30))):
            cv2.rectangle(img, (1015 + 60 * k, 200), (1060 + 60 * k, 290), col, -1)
        return img

    def frames(self) -> Iterator[tuple[np.ndarray, FrameTruth]]:
        rng = np.random.default_rng(self.seed + 1)
        static = self.background()
        cam = self.camera
        base = cam.project(np.array([[0.0, 0.0, 0.0]]))[0]
        for index in range(self.n_frames):
            t = index / self.fps
            img = static.copy()
            draw_robot(img, (int(base[0]), int(base[1])), 1.4, 0.6 * math.sin(t * 0.8))
            fig = self.figure_at(t)
            figures = [fig] if fig else []
            img, visible = _compose(img, figures, [])
            floor = [self.position_at(t)] if fig else []
            truth = FrameTruth(index, t, _truth(visible, img.shape[:2], floor))
            yield add_noise(img, rng), truth


def write_video(path: str | Path, frames: Iterator[tuple[np.ndarray, FrameTruth]],
                fps: float, total: int | None = None, progress: bool = False) -> list[FrameTruth]:
    """Write frames to an MP4 (mp4v) and return the ground truth of every frame.

    ``progress``: a tqdm bar on stderr when it is a terminal (nothing in logs); ``total`` is
    the frame count if known.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer: cv2.VideoWriter | None = None
    truths = []
    if progress:
        frames = _with_progress(frames, total, f"rendering {path.name}")
    try:
        for img, truth in frames:
            if writer is None:
                writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                                         (img.shape[1], img.shape[0]))
                if not writer.isOpened():
                    raise InputError(f"{path}: cannot open a video writer (mp4v)")
            writer.write(img)
            truths.append(truth)
    finally:
        if writer is not None:
            writer.release()
    return truths


def _with_progress(items: Iterator, total: int | None, label: str) -> Iterator:
    """``items`` with a tqdm bar on stderr when it is a terminal; silent otherwise."""
    from monitor.progress import progress

    yield from progress(items, total, label, unit="frame")
