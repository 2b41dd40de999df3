"""Camera health and watch-zone checks on generated scenes (monitor.health).

Frames come from monitor.scene at 15 fps (1280x720, cam0); the watch zone is the demo shelf.
Each scenario states how many frames after the event the fault or alert must appear, from the
default HealthConfig: blinded at once, frozen after 1.0 s, moved after the next moved check
(every 0.25 s) plus 0.5 s, defocused after 2.0 s, scene_change after 3.0 s, cleared after 2.0 s.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from monitor.errors import ConfigError, InputError
from monitor.health import (
    BLINDED,
    DEFOCUSED,
    DEFOCUSED_CLEARED,
    FROZEN,
    LOST,
    MOVED,
    SCENE_CHANGE,
    SCENE_CHANGE_CLEARED,
    CameraHealth,
    HealthConfig,
    HealthReport,
    draw_health,
    load_reference,
)
from monitor.scene import DemoScene, Figure, draw_figure, write_video
from tests.helpers import run_monitor

FPS = 15.0
SHELF = np.array([[1000, 120], [1200, 120], [1200, 300], [1000, 300]], float)
OBJECT = (1070, 135, 1120, 185)  # x1, y1, x2, y2 (exclusive) of a dark box put on the shelf
NO_BOXES = np.zeros((0, 4), np.float32)

Frames = list[tuple[np.ndarray, np.ndarray]]  # (image BGR, person boxes (N, 4) px)


# --- factories ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def demo() -> Frames:
    """10 s of the demo scene (a person walks, the robot moves), with the true person boxes as
    the detector would give them."""
    return [(image, _boxes(truth)) for image, truth in DemoScene(duration_s=10.0).frames()]


@pytest.fixture(scope="module")
def reference() -> np.ndarray:
    return DemoScene().background()


def _boxes(truth) -> np.ndarray:
    return np.array([p.box_px for p in truth.persons], np.float32).reshape(-1, 4)


def checker(reference: np.ndarray | None, **config) -> CameraHealth:
    return CameraHealth(HealthConfig(**config), "cam0", reference, [("shelf", SHELF)])


def play(health: CameraHealth, frames: Frames, start: int = 0) -> list[HealthReport]:
    """Feed frames at 15 fps; frame i of the list is at (start + i) / FPS seconds."""
    return [health.check(image, (start + i) / FPS, boxes)
            for i, (image, boxes) in enumerate(frames)]


def onsets(reports: list[HealthReport]) -> list[tuple[int, str]]:
    """(frame, fault name) for each frame where a fault became active."""
    out, active = [], set()
    for i, report in enumerate(reports):
        names = {f.name for f in report.faults}
        out.extend((i, name) for name in sorted(names - active))
        active = names
    return out


def alerts(reports: list[HealthReport]) -> list[tuple[int, str]]:
    return [(i, a.kind) for i, r in enumerate(reports) for a in r.alerts]


def with_object(image: np.ndarray) -> np.ndarray:
    out = image.copy()
    cv2.rectangle(out, OBJECT[:2], (OBJECT[2] - 1, OBJECT[3] - 1), (30, 30, 30), -1)
    return out


def with_cable(image: np.ndarray) -> np.ndarray:
    """A loose black cable, 5 px thick, hanging down across the shelf."""
    out = image.copy()
    cable = np.array([[1040, 120], [1050, 170], [1035, 230], [1045, 290]], np.int32)
    cv2.polylines(out, [cable], False, (20, 20, 20), 5)
    return out


def noisy(image: np.ndarray, rng: np.random.Generator, sigma: float = 2.0) -> np.ndarray:
    return np.clip(image + rng.normal(0.0, sigma, image.shape[:2])[..., None], 0, 255).astype(
        np.uint8)


def _drawn_red(drawn: np.ndarray, original: np.ndarray) -> np.ndarray:
    """Pure red pixels of ``drawn`` that were not red in ``original`` (the shelf has a red box)."""
    def red(img):
        return (img[..., 2] > 200) & (img[..., 1] < 80) & (img[..., 0] < 80)
    was_red = cv2.dilate(red(original).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    return red(drawn) & ~was_red


def iou(a, b) -> float:
    ix = max(0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


# --- normal operation ---------------------------------------------------------------------------

@pytest.mark.parametrize("with_reference", [pytest.param(True, id="reference"),
                                            pytest.param(False, id="no-reference")])
def test_normal_scene_raises_nothing(demo, reference, with_reference):
    reports = play(checker(reference if with_reference else None), demo)
    assert onsets(reports) == []
    assert alerts(reports) == []
    assert reports[-1].zones[0].state == "normal"
    assert set(reports[-1].timings_ms) >= {"prepare", "blinded", "frozen", "defocus", "moved",
                                           "scene", "total"}


@pytest.mark.slow
def test_half_a_minute_of_the_looped_demo_scene_raises_nothing(reference):
    health = checker(reference)
    seen_faults: list[tuple[int, str]] = []
    seen_alerts: list[tuple[int, str]] = []
    # the 24 s walk and its loop seam (the jump back to the start, where a naive scene-change
    # check would fire), and the second round's first 6 s
    scene = DemoScene(duration_s=30.0, loop=True)
    for i, (image, truth) in enumerate(scene.frames()):
        report = health.check(image, i / scene.fps, _boxes(truth))
        seen_faults.extend((i, f.name) for f in report.faults)
        seen_alerts.extend((i, a.kind) for a in report.alerts)
    assert i == 449
    assert seen_faults == []
    assert seen_alerts == []


# --- camera integrity ---------------------------------------------------------------------------

def test_frozen_feed_is_a_stop_fault_after_one_second(demo, reference):
    frames = demo[:45] + [demo[44]] * 30 + demo[45:60]  # frame 44 repeated from index 45 on
    reports = play(checker(reference), frames)
    assert onsets(reports) == [(59, FROZEN)]  # 1.0 s after the last picture that changed
    fault = reports[59].faults[0]
    assert fault.stop and fault.source == "cam0" and "unchanged for 1.0 s" in fault.reason
    assert [r.picture_changed for r in reports[43:47]] == [True, True, False, False]
    # live again from index 75: it ends once every frame has changed for 0.5 s (8 frames)
    assert all(r.faults for r in reports[59:83]) and not reports[83].faults
    assert "changing again" in reports[80].faults[0].reason
    assert [r.picture_changed for r in reports[74:77]] == [False, False, True]
    assert alerts(reports) == []


def _codec_jump(image: np.ndarray, level: int = 2) -> np.ndarray:
    """What a keyframe does to a repeated picture: the same scene, re-encoded (here: every
    other 16 px block ``level`` grey levels brighter, about 1 grey level of mean difference
    at the analysis size; mp4v and H.264 give 0.3-0.8)."""
    out = image.astype(np.int16)
    blocks = ((np.arange(image.shape[0])[:, None] // 16 + np.arange(image.shape[1]) // 16)
              % 2).astype(np.int16)
    out += level * blocks[:, :, None]
    return np.clip(out, 0, 255).astype(np.uint8)


def test_a_keyframe_once_a_second_in_a_repeated_picture_neither_restarts_nor_ends_a_freeze(
        demo, reference):
    """The stream repeats frame 44 for 3 s, with a codec's keyframe every 15 frames (a lone
    jump above frozen_diff, then the repeated keyframe picture): frozen 1.0 s after the last
    real picture, and frozen for as long as it repeats (a jump that restarted the timer gave
    camera_frozen 2 s late; one that ended it cleared the fault in a frozen stream)."""
    still = demo[44][0]
    jumped = _codec_jump(still)
    frozen = [(jumped if (k // 15) % 2 else still, NO_BOXES) for k in range(1, 46)]
    health = checker(reference)
    reports = play(health, demo[:45] + frozen)
    jump = reports[45 + 14].measures  # the jump counts as a difference beyond the noise
    assert jump["frame_diff"] > jump["frozen_threshold"] >= 0.3
    assert onsets(reports) == [(59, FROZEN)]
    assert all(r.faults for r in reports[59:])
    assert not any(r.picture_changed for r in reports[45:])


def test_a_freeze_ends_only_after_the_picture_changes_like_a_live_camera(demo, reference):
    """After a freeze, two frames that change (a camera stepping through a few stored frames,
    a keyframe and its successor) do not end camera_frozen; 0.5 s of live frames do."""
    frames = demo[:45] + [demo[44]] * 20 + [demo[50], demo[51]] + [demo[51]] * 10 + demo[52:80]
    reports = play(checker(reference), frames)
    assert onsets(reports) == [(59, FROZEN)]
    first_live = 45 + 20 + 2 + 10
    assert all(r.faults for r in reports[59:first_live + 7])
    assert not reports[first_live + 8].faults


@pytest.mark.parametrize("level,reason", [
    pytest.param(0, "too dark", id="covered-black"),
    pytest.param(255, "overexposed", id="flash-white"),
    pytest.param(120, "covered", id="covered-grey"),
])
def test_blinded_camera_is_a_stop_fault_at_once(demo, reference, level, reason):
    blind = [(np.full_like(demo[0][0], level), NO_BOXES)] * 45  # 3 s: also not "frozen"
    frames = demo[:45] + blind + demo[45:150]
    reports = play(checker(reference), frames)
    assert onsets(reports) == [(45, BLINDED)]
    assert all(f.name == BLINDED and f.stop and reason in f.reason
               for r in reports[45:90] for f in r.faults)
    assert reports[89].faults and not reports[90].faults  # clears with the first sound frame
    assert alerts(reports) == []  # the watch zone did not learn the blank image


def test_short_flash_raises_nothing_afterwards(demo, reference):
    flash = [(np.full_like(demo[0][0], 255), NO_BOXES)] * 3
    reports = play(checker(reference), demo[:45] + flash + demo[45:150])
    assert onsets(reports) == [(45, BLINDED)]
    assert [i for i, r in enumerate(reports) if r.faults] == [45, 46, 47]
    assert alerts(reports) == []


def test_blur_is_a_defocus_warning_after_two_seconds(demo, reference):
    rng = np.random.default_rng(1)
    # optical blur, then sensor noise again (a defocused camera still has noise)
    blurred = [(noisy(cv2.GaussianBlur(image, (0, 0), 3.0), rng), boxes)
               for image, boxes in demo[45:120]]
    frames = demo[:45] + blurred + demo[:60]
    reports = play(checker(reference), frames)
    assert onsets(reports) == [(75, DEFOCUSED)]  # 30 frames (2.0 s) after the blur began
    fault = reports[75].faults[0]
    assert not fault.stop and "blurred" in fault.reason
    # sharp again from frame 120: cleared after clear_time_s (2.0 s = 30 frames)
    assert alerts(reports) == [(75, DEFOCUSED), (150, DEFOCUSED_CLEARED)]
    assert reports[75].alerts[0].severity == "warning"
    assert reports[75].alerts[0].snapshot_jpeg[:2] == b"\xff\xd8"
    assert reports[149].faults and not reports[150].faults


@pytest.mark.parametrize("dx,dy", [pytest.param(20, 0, id="right-20px"),
                                   pytest.param(0, -20, id="up-20px")])
def test_camera_shifted_by_20_px_is_a_stop_fault(demo, reference, dx, dy):
    shift = np.float32([[1, 0, dx], [0, 1, dy]])
    moved = [(cv2.warpAffine(image, shift, (1280, 720), borderMode=cv2.BORDER_REPLICATE), boxes)
             for image, boxes in demo[45:90]]
    reports = play(checker(reference), demo[:45] + moved)
    found = onsets(reports)
    assert [name for _, name in found] == [MOVED]
    # next moved check (<= 0.25 s = 4 frames) + moved_after_s (0.5 s = 8 frames)
    assert 45 < found[0][0] <= 45 + 12
    fault = reports[-1].faults[0]
    assert fault.stop
    shift_px = float(fault.reason.split("shifted by ")[1].split(" px")[0])
    assert abs(shift_px - 20) <= 1.5
    # the direction in full-resolution pixels, so an integrator can re-aim the camera (within
    # a pixel: the person's box weighs nothing in the comparison, a little less view to match)
    got = fault.reason.split("(dx ")[1].split("; limit 8 px)")[0]
    got_dx, got_dy = (int(v) for v in got.replace("dy ", "").split(", "))
    assert abs(got_dx - dx) <= 1 and abs(got_dy - dy) <= 1, fault.reason
    assert alerts(reports) == []  # the zone's change is the camera's move, not the scene's


def test_small_shift_is_not_a_fault(demo, reference):
    shift = np.float32([[1, 0, 3], [0, 1, 2]])
    moved = [(cv2.warpAffine(image, shift, (1280, 720), borderMode=cv2.BORDER_REPLICATE), boxes)
             for image, boxes in demo[:90]]
    reports = play(checker(reference), moved)
    assert onsets(reports) == []
    assert alerts(reports) == []


def test_other_view_does_not_match_the_reference(demo, reference):
    turned = cv2.rotate(reference, cv2.ROTATE_180)
    reports = play(checker(turned), demo[:30])
    assert [name for _, name in onsets(reports)] == [MOVED]
    assert reports[-1].faults[0].reason.endswith("camera moved, turned or view blocked")
    # the numbers behind it, for the replay summary: a poor match, whatever the shift
    measured = [r.measures for r in reports if "match" in r.measures]
    assert measured and all(m["match"] < 0.2 and m["shift_px"] >= 0 for m in measured)


def test_lost_camera():
    health = checker(None)
    assert health.check_lost(5.0).reason == "cam0: no frame received yet"
    health.check(np.full((720, 1280, 3), 128, np.uint8), 10.0, NO_BOXES)
    assert health.check_lost(10.9) is None
    fault = health.check_lost(11.5)
    assert fault.name == LOST and fault.stop and "no frame for 1.5 s" in fault.reason
    assert health.check_lost(11.5, last_frame_time=11.0) is None  # the caller's frame time


# --- watch zones --------------------------------------------------------------------------------

def test_object_in_watch_zone_raises_scene_change_with_outlined_snapshot(demo, reference):
    placed = [(with_object(image), boxes) for image, boxes in demo[45:135]]
    frames = demo[:45] + placed + demo[135:150] + demo[:30]  # removed again at frame 135
    reports = play(checker(reference), frames)
    # 3.0 s (45 frames) after it appeared; cleared 2.0 s (30 frames) after it went
    assert alerts(reports) == [(90, SCENE_CHANGE), (165, SCENE_CHANGE_CLEARED)]
    assert onsets(reports) == []
    alert = reports[90].alerts[0]
    assert alert.severity == "warning" and alert.source == "cam0"
    assert alert.details["zone"] == "shelf"
    assert iou(alert.details["box_px"], OBJECT) > 0.5
    assert [z.state for z in reports[89].zones] == ["pending"]
    assert [z.state for z in reports[90].zones] == ["active"]
    # the snapshot outlines the change in red around the object, not elsewhere in the zone
    snap = cv2.imdecode(np.frombuffer(alert.snapshot_jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert snap.shape == (720, 1280, 3)
    red = _drawn_red(snap, frames[90][0])
    x1, y1, x2, y2 = OBJECT
    ring = red[y1 - 14:y2 + 14, x1 - 14:x2 + 14].copy()
    assert ring.sum() > 2 * (x2 - x1 + y2 - y1)  # a rectangle around the object
    assert not red[y1 + 4:y2 - 4, x1 + 4:x2 - 4].any()  # the object itself stays visible
    rest = red[120:300, 1000:1200].copy()
    rest[y1 - 120 - 14:y2 - 120 + 14, x1 - 1000 - 14:x2 - 1000 + 14] = False
    assert not rest.any()


def test_loose_cable_in_watch_zone_raises_scene_change(demo, reference):
    placed = [(with_cable(image), boxes) for image, boxes in demo[45:105]]
    reports = play(checker(reference), demo[:45] + placed)
    assert alerts(reports) == [(90, SCENE_CHANGE)]
    x1, y1, x2, y2 = reports[90].alerts[0].details["box_px"]
    assert x1 >= 1020 and x2 <= 1065 and y1 <= 140 and y2 >= 270


@pytest.mark.parametrize("change", [
    pytest.param(lambda im: (im * 0.8).astype(np.uint8), id="dimmed-20pct"),
    pytest.param(lambda im: np.clip(im * 1.2, 0, 255).astype(np.uint8), id="brighter-20pct"),
    pytest.param(lambda im: np.clip(im.astype(np.int16) + 25, 0, 255).astype(np.uint8),
                 id="offset+25"),
])
def test_lighting_change_is_not_a_scene_change(demo, reference, change):
    relit = [(change(image), boxes) for image, boxes in demo[45:150]]
    reports = play(checker(reference), demo[:45] + relit)
    assert alerts(reports) == []
    assert onsets(reports) == []


def test_scene_change_without_reference_learns_the_first_frame(demo):
    placed = [(with_object(image), boxes) for image, boxes in demo[30:90]]
    reports = play(checker(None), demo[:30] + placed)
    assert alerts(reports) == [(75, SCENE_CHANGE)]


def test_short_change_raises_nothing(demo, reference):
    placed = [(with_object(image), boxes) for image, boxes in demo[45:75]]  # 2 s < 3 s
    reports = play(checker(reference), demo[:45] + placed + demo[75:150])
    assert alerts(reports) == []


def _walk_through_shelf(reference: np.ndarray) -> Frames:
    """A person walks in front of the shelf (2 s), stands there (4 s, longer than
    persist_time_s) and walks out (2 s), then 3 s of the empty scene."""
    rng = np.random.default_rng(7)
    frames: Frames = []
    path = ([880 + 220 * k / 30 for k in range(30)] + [1100.0] * 60
            + [1100 + 220 * k / 30 for k in range(30)])
    for k, x in enumerate(path):
        fig = Figure((x, 330.0), 260.0, phase=k * 0.5, stride=0.0 if 30 <= k < 90 else 0.45,
                     arm_raise=0.3 if 30 <= k < 90 else 0.0)
        image = reference.copy()
        draw_figure(image, fig)
        mask = np.zeros(image.shape[:2], np.uint8)
        draw_figure(mask, Figure(fig.feet_px, fig.height_px, fig.phase, fig.arm_raise,
                                 ((255,),) * 4, fig.stride))
        x0, y0, w, h = cv2.boundingRect(mask)
        frames.append((noisy(image, rng), np.array([[x0, y0, x0 + w, y0 + h]], np.float32)))
    frames += [(noisy(reference, rng), NO_BOXES) for _ in range(45)]
    return frames


def test_person_walking_through_watch_zone_raises_nothing(reference):
    frames = _walk_through_shelf(reference)
    reports = play(checker(reference), frames)
    assert alerts(reports) == []
    assert onsets(reports) == []
    # the same frames without person boxes: the change is seen (the boxes are what matters)
    unboxed = play(checker(reference), [(image, NO_BOXES) for image, _ in frames])
    assert SCENE_CHANGE in [kind for _, kind in alerts(unboxed)]


# --- reference capture (real subprocess, real files) --------------------------------------------

_cli = run_monitor


def test_reference_capture_accepts_a_deliberate_change(demo, reference, tmp_path):
    changed = [(with_object(image), boxes) for image, boxes in demo[:75]]
    write_video(tmp_path / "changed.mp4", ((img, None) for img, _ in changed[:15]), FPS)
    result = _cli("reference", "capture", "--source", str(tmp_path / "changed.mp4"),
                  "--out", str(tmp_path), "--camera", "cam0")
    assert result.returncode == 0, result.stderr
    assert "cam0" in result.stdout and "median of 15 frames" in result.stdout
    new_reference = load_reference(tmp_path / "cam0.png")
    assert new_reference.shape == (720, 1280, 3)
    assert not list(tmp_path.glob(".*.tmp"))  # the temp file was renamed, not left behind
    # with the old reference the object is a change; with the new one it is the normal scene
    assert [k for _, k in alerts(play(checker(reference), changed))] == [SCENE_CHANGE]
    after = play(checker(new_reference), changed)
    assert alerts(after) == [] and onsets(after) == []


def test_reference_capture_of_a_missing_source_is_one_line_error(tmp_path):
    result = _cli("reference", "capture", "--source", str(tmp_path / "nope.mp4"),
                  "--out", str(tmp_path / "ref.png"))
    assert result.returncode == 2
    assert result.stderr.startswith("monitor: error: ") and result.stderr.count("\n") == 1
    assert not (tmp_path / "ref.png").exists()


# --- configuration and input errors ------------------------------------------------------------

@pytest.mark.parametrize("field,value", [
    pytest.param("persist_time_s", -1.0, id="negative-time"),
    pytest.param("analysis_width", 10, id="tiny-analysis"),
    pytest.param("defocus_ratio", 2.0, id="ratio-above-1"),
    pytest.param("scene_diff", math.nan, id="nan"),
])
def test_bad_config_is_refused(field, value):
    with pytest.raises(ConfigError, match=f"health.{field}"):
        HealthConfig(**{field: value})


def test_reference_of_other_aspect_is_refused():
    health = checker(np.zeros((480, 640, 3), np.uint8) + 100)
    with pytest.raises(InputError, match="aspect"):
        health.check(np.full((720, 1280, 3), 100, np.uint8), 0.0, NO_BOXES)


def test_zone_outside_the_image_is_refused():
    health = CameraHealth(HealthConfig(), "cam0", None,
                          [("far", np.array([[2000, 10], [2100, 10], [2100, 90]], float))])
    with pytest.raises(ConfigError, match="zone far"):
        health.check(np.full((720, 1280, 3), 100, np.uint8), 0.0, NO_BOXES)


def test_frame_size_change_is_refused(demo, reference):
    health = checker(reference)
    health.check(demo[0][0], 0.0, NO_BOXES)
    with pytest.raises(InputError, match="frame size changed"):
        health.check(cv2.resize(demo[1][0], (640, 360)), 0.1, NO_BOXES)


def test_set_reference_accepts_a_change_at_run_time(demo, reference):
    placed = [(with_object(image), boxes) for image, boxes in demo[45:150]]
    health = checker(reference)
    first = play(health, demo[:45] + placed[:60])
    assert alerts(first) == [(90, SCENE_CHANGE)]
    health.set_reference(with_object(DemoScene().background()))
    later = play(health, placed[60:], start=105)
    assert alerts(later) == [] and onsets(later) == []
    assert {z.state for z in later[-1].zones} == {"normal"}


def test_draw_health_outlines_the_change(demo, reference):
    placed = [(with_object(image), boxes) for image, boxes in demo[:60]]
    report = play(checker(reference), placed)[-1]
    canvas = placed[-1][0].copy()
    draw_health(canvas, report, [("shelf", SHELF)])
    red = _drawn_red(canvas, placed[-1][0])
    x1, y1, x2, y2 = OBJECT
    assert red[y1 - 10:y2 + 10, x1 - 10:x2 + 10].sum() > 100
