"""The work around inference made cheaper (issue 49) gives the same answers as the plain way.

Each test compares a stage's faster code with a direct, obviously correct computation of the
same thing, on frames and layouts that take every branch (padding left/right or top/bottom,
RGB and BGR, NCHW and NHWC, a reused canvas after a change of frame size)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from monitor.detector import Letterboxer, ModelLayout


def _plain_letterbox(image: np.ndarray, layout: ModelLayout) -> np.ndarray:
    """Resize into a fresh padded canvas, reorder the channels, scale: one frame, no reuse."""
    h, w = image.shape[:2]
    box = Letterboxer(layout)(image)[1]
    nw, nh = max(1, round(w * box.scale)), max(1, round(h * box.scale))
    px, py = int(box.pad_x), int(box.pad_y)
    canvas = np.full((box.input_height, box.input_width, 3), layout.pad_value, np.uint8)
    cv2.resize(image, (nw, nh), dst=canvas[py:py + nh, px:px + nw],
               interpolation=cv2.INTER_LINEAR)
    rgb = canvas[..., ::-1] if layout.rgb else canvas
    tensor = rgb.astype(np.float64) * layout.scale
    if not layout.input_nhwc:
        tensor = tensor.transpose(2, 0, 1)
    return tensor[None].astype(np.float32)


def _plain_fit(cur, bg, tolerance):
    """The objects watch's lighting fit as first written (np.median, np.cov): the plain
    reference the fast fit is compared with."""
    cur, bg = cur.astype(np.float32), bg.astype(np.float32)
    offset = float(np.median(cur - bg))
    use = np.abs(cur - bg - offset) < tolerance
    gain = 1.0
    if use.sum() >= 30:
        x, y = bg[use].astype(np.float64), cur[use].astype(np.float64)
        var = float(x.var())
        if var >= 25.0:
            gain = min(max(float(np.cov(x, y, bias=True)[0, 1]) / var, 0.5), 2.0)
        offset = float(y.mean() - gain * x.mean())
    return gain, offset


@pytest.mark.parametrize("layout", [
    ModelLayout("darknet", "x", 416, 416),
    ModelLayout("darknet", "x", 416, 416, rect=True),
    ModelLayout("yolox", "x", 416, 416, rgb=False, scale=1.0, centered=False),
    ModelLayout("yolov5", "x", 320, 320, input_nhwc=True),
], ids=["square", "rectangular", "bgr-top-left", "nhwc"])
def test_letterbox_tensor_is_the_plain_resize_reorder_and_scale(layout):
    rng = np.random.default_rng(7)
    letterboxer = Letterboxer(layout)  # one instance: its canvas and planes are reused
    for shape in [(1080, 1920), (1080, 1920), (720, 1280), (1920, 1080), (301, 199), (1, 1)]:
        image = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
        tensor, _ = letterboxer(image)
        expected = _plain_letterbox(image, layout)
        assert tensor.shape == expected.shape
        np.testing.assert_allclose(tensor, expected, rtol=0, atol=1e-6)


def test_one_placement_a_frame_gives_the_zone_answer_and_cut_rows_of_two():
    """The pipeline places a frame's boxes once (``seen_placement``) for the zone check and
    the tracks' cut-off feet: the same answers as each placing them itself, for persons on
    the floor, one cut off by the image bottom, one too wide for one person (its ends are
    checked apart) and none; non-finite boxes keep the zone check's own error."""
    from monitor.config import demo_cell_path
    from monitor.errors import InputError
    from monitor.pipeline.locate import check_seen, cut_feet_rows, seen_placement
    from monitor.zones import parse_cell, read_cell_data

    cell = parse_cell(read_cell_data(demo_cell_path()), demo_cell_path())
    prepared = cell.prepared
    cam = next(iter(cell.cameras))
    foot = 12.0
    sets = [np.array([[600.0, 200.0, 660.0, 380.0], [300.0, 150.0, 340.0, 260.0]]),
            np.array([[500.0, 500.0, 580.0, 720.0]]),  # feet below the image
            np.array([[400.0, 250.0, 700.0, 450.0]]),  # two persons side by side?
            np.zeros((0, 4))]
    hits = 0
    for boxes in sets:
        placed = seen_placement(prepared, cam, boxes, foot)
        assert (placed is None) == (not len(boxes))
        shared = check_seen(prepared, cam, boxes, None, None, foot, None, placed)
        own = check_seen(prepared, cam, boxes, None, None, foot, None)
        assert shared == own
        hits += len(own.hits)
        a = cut_feet_rows(prepared, cam, boxes, foot, placed)
        b = cut_feet_rows(prepared, cam, boxes, foot)
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)
    assert hits, "no box hit a zone: the comparison shows nothing"
    bad = np.array([[np.nan, 1.0, 2.0, 3.0]])
    assert seen_placement(prepared, cam, bad, foot) is None
    with pytest.raises(InputError, match="non-finite"):
        check_seen(prepared, cam, bad, None, None, foot, None, None)


def test_the_objects_watch_finds_what_the_plain_comparison_finds():
    """The objects-since-commissioning watch compares each frame with the reference: its
    pixels taken by ``np.compress`` and its excess maximised channel by channel give the same
    changed pixels as boolean indexing and ``max(axis=2)``, and a frame without a lasting
    change skips the labelling: with a crate put into the protective zone, persons walking by,
    an unsound frame and the light switched down, every frame's streaks, objects and alerts
    are those of the plain comparison."""
    from monitor.config import demo_cell_path
    from monitor.health.objects import ZoneObjects, objects_of
    from monitor.scene import DemoScene
    from monitor.zones import parse_cell, read_cell_data

    class Plain(ZoneObjects):
        def _changed(self, small, free):  # as written before (issue 49): the reference
            ref, frame = self._ref, small.astype(np.float32)
            if free.sum() < 50:
                return np.zeros(free.shape, bool)
            gain, offset = _plain_fit(frame[free].ravel(), ref[free].ravel(),
                                      2 * self.config.diff)
            excess = np.abs(frame - (gain * ref + offset)).max(axis=2)
            return (excess > self.config.diff) & self._watch

        def _objects(self, lasting, not_back, now, image_bgr):
            # the labelling always runs: an all-empty image has no region either
            cv2.connectedComponentsWithStats(lasting.astype(np.uint8), 8)
            return super()._objects(lasting, not_back, now, image_bgr)

    cell = parse_cell(read_cell_data(demo_cell_path()), demo_cell_path())
    scene = DemoScene(fps=10.0)
    reference = scene.background()
    fast = objects_of(cell, {"cam0": reference})["cam0"]
    plain = objects_of(cell, {"cam0": reference})["cam0"]
    plain.__class__ = Plain
    alerts: tuple[list, list] = ([], [])
    for k, (image, _) in enumerate(scene.frames()):
        t = k / scene.fps
        if k >= 100:
            break
        image = image.copy()
        if k >= 10:
            cv2.rectangle(image, (470, 400), (600, 520), (40, 90, 200), -1)  # a crate
        if k >= 70:
            image = (image * 0.7).astype(np.uint8)  # the light switched down
        persons = np.array([[300.0 + 4 * k, 200, 370 + 4 * k, 470]]) if k % 3 else \
            np.zeros((0, 4))
        sound = k % 31 != 7
        alerts[0].extend(a.message for a in fast.check(image, persons, t, sound))
        alerts[1].extend(a.message for a in plain.check(image, persons, t, sound))
        np.testing.assert_array_equal(fast._since, plain._since)
        assert repr(fast.objects) == repr(plain.objects), k
        assert (fast.version, fast.view_changed_since) == (plain.version,
                                                           plain.view_changed_since)
    assert alerts[0] == alerts[1]
    assert fast.objects and any("object" in a for a in alerts[0]), "no object: shows nothing"


def test_the_lighting_fit_in_whole_levels_is_the_plain_median_and_least_squares():
    """The objects watch's lighting fit (a histogram median, int64 sums) gives the gain and
    offset np.median and np.cov give on the same pixels: odd and even counts, a light switched
    down with noise, a flat view (no gain), too few pixels near the median (no fit), clipping."""
    from monitor.health.objects import lighting_fit

    plain = _plain_fit

    rng = np.random.default_rng(3)
    cases = []
    for n in (50, 51, 1000, 1001, 107064):
        bg = rng.integers(0, 256, n).astype(np.uint8)
        for gain, noise in ((1.0, 0.0), (0.7, 3.0), (1.3, 8.0), (0.2, 1.0)):
            cur = np.clip(bg * gain + 12 + rng.normal(0, noise, n), 0, 255).astype(np.uint8)
            cases.append((cur, bg))
    flat = np.full(500, 90, np.uint8)
    cases.append((np.clip(flat + rng.normal(0, 2, 500), 0, 255).astype(np.uint8), flat))
    scattered = rng.integers(0, 256, 60).astype(np.uint8)  # few pixels near the median
    cases.append((rng.integers(0, 256, 60).astype(np.uint8), scattered))
    for cur, bg in cases:
        for tolerance in (60.0, 7.5, 0.5):
            got, want = lighting_fit(cur, bg, tolerance), plain(cur, bg, tolerance)
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
