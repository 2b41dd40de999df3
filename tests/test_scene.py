"""Synthetic scenes: deterministic, with consistent ground truth."""

from __future__ import annotations

import hashlib

import cv2
import numpy as np
import pytest

from monitor.scene import DEMO_CAMERA, DemoScene, random_frames, write_video
from monitor.scene.cell import Block, CellScene, CutOut, Walker


def test_same_seed_same_frames_other_seed_other_frames():
    a = list(random_frames(3, seed=5, size=(640, 360)))
    b = list(random_frames(3, seed=5, size=(640, 360)))
    c = list(random_frames(3, seed=6, size=(640, 360)))
    assert all(np.array_equal(x[0], y[0]) and x[1] == y[1] for x, y in zip(a, b, strict=True))
    assert not all(np.array_equal(x[0], y[0]) for x, y in zip(a, c, strict=True))


def test_ground_truth_boxes_are_visible_parts_of_the_figures():
    seen_occluded = False
    with_distractors = 0
    for _image, truth in random_frames(40, seed=1):
        for p in truth.persons:
            x1, y1, x2, y2 = p.box_px
            fx1, fy1, fx2, fy2 = p.full_box_px
            assert 0 <= x1 < x2 <= 1280 and 0 <= y1 < y2 <= 720
            assert fx1 <= x1 and fy1 <= y1 and x2 <= fx2 and y2 <= fy2
            assert 0 < p.visible_fraction <= 1
            seen_occluded |= p.visible_fraction < 0.95
        with_distractors += bool(truth.distractor_boxes_px)
    assert seen_occluded
    assert with_distractors >= 32  # most frames hold a sticker or mannequins (when they fit)


def test_demo_person_walks_in_and_out_and_the_camera_projects_the_cell():
    scene = DemoScene(duration_s=24, fps=5)
    truths = [t for _, t in scene.frames()]
    present = [bool(t.persons) for t in truths]
    assert not present[0] and any(present) and not present[-1]
    origin = DEMO_CAMERA.project(np.array([[0.0, 0.0, 0.8]]))[0]
    np.testing.assert_allclose(origin, [640, 360], atol=1e-6)  # it looks at the target


def test_write_video_gives_a_readable_mp4(tmp_path):
    path = tmp_path / "demo.mp4"
    truths = write_video(path, DemoScene(duration_s=1.0, fps=10).frames(), 10)
    cap = cv2.VideoCapture(str(path))
    assert cap.get(cv2.CAP_PROP_FRAME_COUNT) == len(truths) == 10
    ok, frame = cap.read()
    assert ok and frame.shape == (720, 1280, 3)


# ---------------------------------------------------------------------------- cell scenes

def test_demo_scene_is_unchanged_byte_for_byte():
    # frames and ground truth of the demo scene as rendered before the scene package existed
    m = hashlib.sha256()
    for img, truth in DemoScene(duration_s=2.0, fps=5).frames():
        m.update(img.tobytes())
        m.update(repr(truth).encode())
    assert m.hexdigest() == "bbd4a52680d9b1003b850e9fc44d158f6f1329d833704e455ae9440aacd539c1"


def _one_frame(scene: CellScene):
    return scene.render(scene.background(), 0, 0.0)


def test_bench_in_front_hides_the_legs_and_truth_keeps_the_feet():
    scene = CellScene((Walker(((0.0, 0.0, -0.6),)),),
                      (Block("bench", (-1.2, -1.6, 0.0), (1.2, -1.05, 1.15)),), noise=False)
    _img, truth = _one_frame(scene)
    (p,) = truth.persons
    assert p.floor_m == (0.0, -0.6)
    assert 0.2 < p.visible_fraction < 0.8
    assert p.box_px[3] < p.full_box_px[3] - 10  # visible bottom on the bench top
    feet = scene.camera.project(np.array([[0.0, -0.6, 0.0]]))[0]
    assert abs(p.full_box_px[3] - feet[1]) < 4


def test_wholly_hidden_person_stays_in_the_ground_truth():
    scene = CellScene((Walker(((0.0, 0.0, -0.6),), posture="crouching"),),
                      (Block("cabinet", (-0.8, -1.6, 0.0), (0.8, -1.05, 2.2)),), noise=False)
    img, truth = _one_frame(scene)
    (p,) = truth.persons
    assert p.visible_fraction == 0.0 and p.box_px is None and p.full_box_px is not None
    assert p.posture == "crouching" and p.height_m == pytest.approx(1.75 * 0.58)
    # nothing of the person is drawn: no work-wear pixels
    b, g, r = (img[..., k].astype(int) for k in range(3))
    assert not np.any((r + b - 2 * g) >= 1.55 * 255 * 0.9)


def test_painters_order_person_in_front_of_the_bench_is_whole():
    scene = CellScene((Walker(((0.0, 0.0, -2.0),)),),
                      (Block("bench", (-1.2, -1.6, 0.0), (1.2, -1.05, 1.15)),), noise=False)
    _img, truth = _one_frame(scene)
    assert truth.persons[0].visible_fraction == 1.0


@pytest.mark.parametrize("posture", ["standing", "kneeling", "crouching"])
def test_posed_figures_have_the_height_of_their_posture(posture):
    scene = CellScene((Walker(((0.0, 0.0, -2.0),), posture=posture),), noise=False,
                      robot=False)
    _img, truth = _one_frame(scene)
    (p,) = truth.persons
    feet, head = scene.camera.project(np.array([[0.0, -2.0, 0.0], [0.0, -2.0, p.height_m]]))
    got = p.full_box_px[3] - p.full_box_px[1]
    assert abs(got - (feet[1] - head[1])) <= 0.08 * (feet[1] - head[1]) + 3, (posture, got)


def test_running_has_a_longer_stride_and_a_matching_cadence():
    walk = CellScene((Walker(((0.0, 0.0, 0.0), (2.0, 2.8, 0.0))),))
    run = CellScene((Walker(((0.0, 0.0, 0.0), (1.0, 2.8, 0.0)), running=True),))
    fw, fr = walk._figure(0, 0.5), run._figure(0, 0.5)
    assert fr.stride > fw.stride > 0
    # phase advances one cycle per 1.4 m walking, per 2.2 m running
    assert fw.phase == pytest.approx(0.7 / 1.4 * 2 * np.pi)
    assert fr.phase == pytest.approx(1.4 / 2.2 * 2 * np.pi)


def test_cut_out_is_person_coloured_but_not_a_person():
    scene = CellScene((), cutouts=(CutOut((1.5, -1.5)),), noise=False, robot=False)
    img, truth = _one_frame(scene)
    assert truth.persons == ()
    b, g, r = (img[..., k].astype(int) for k in range(3))
    assert np.any((r + b - 2 * g) >= 1.55 * 255)


def test_cell_scene_is_deterministic():
    scene = CellScene((Walker(((0.0, -2.0, -1.0), (1.0, 0.0, -1.0))),), duration_s=0.3)
    a = list(scene.frames())
    b = list(scene.frames())
    assert all(np.array_equal(x[0], y[0]) and x[1] == y[1] for x, y in zip(a, b, strict=True))


def test_write_video_progress_is_silent_off_a_terminal(tmp_path, capsys):
    truths = write_video(tmp_path / "p.mp4", DemoScene(duration_s=1.0, fps=10).frames(), 10,
                         total=10, progress=True)
    assert len(truths) == 10
    assert capsys.readouterr().err == ""  # logs hold results only (a tty gets a bar)
