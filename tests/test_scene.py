"""Synthetic scenes: deterministic, with consistent ground truth."""

from __future__ import annotations

import cv2
import numpy as np

from monitor.scene import DEMO_CAMERA, DemoScene, random_frames, write_video


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
