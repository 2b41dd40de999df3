"""Box algebra at its edges: degenerate and sub-pixel boxes, exact thresholds, ties, dtypes.

Each case is a behaviour the detector's post-processing relies on (found by mutation testing of
monitor/geometry/boxes.py: these are the bugs the broader tests in test_boxes.py could not see)."""

from __future__ import annotations

import numpy as np
import pytest

from monitor.geometry.boxes import area, gap_matrix, ios_matrix, iou_matrix, merge_boxes, nms


def b(*rows) -> np.ndarray:
    return np.array(rows, np.float64).reshape(-1, 4)


def test_inverted_boxes_have_no_area_and_thin_ones_their_true_area() -> None:
    assert area(b([10, 10, 5, 20], [10, 10, 20, 5])).tolist() == [0.0, 0.0]
    # sub-pixel widths and heights count exactly (no rounding up to a pixel)
    assert area(b([0, 0, 0.5, 10], [0, 0, 10, 0.25])).tolist() == [5.0, 2.5]


def test_disjoint_boxes_have_no_overlap_even_when_they_share_rows_or_columns() -> None:
    side = b([0, 0, 10, 10], [20, 0, 30, 10])  # same rows, apart in x
    above = b([0, 0, 10, 10], [0, 20, 10, 30])  # same columns, apart in y
    for pair in (side, above):
        assert iou_matrix(pair[:1], pair[1:])[0, 0] == 0.0
        assert ios_matrix(pair[:1], pair[1:])[0, 0] == 0.0


def test_a_half_pixel_overlap_counts_exactly() -> None:
    a, c = b([0, 0, 10, 10]), b([9.5, 0, 20, 10])  # 0.5 px wide strip
    assert ios_matrix(a, c)[0, 0] == pytest.approx(5.0 / 100.0)
    a, c = b([0, 0, 10, 10]), b([0, 9.5, 10, 20])
    assert ios_matrix(a, c)[0, 0] == pytest.approx(5.0 / 100.0)


def test_ratios_of_tiny_and_empty_boxes() -> None:
    tiny = b([0, 0, 0.5, 0.5])  # area 0.25: less than one pixel
    assert iou_matrix(tiny, tiny)[0, 0] == pytest.approx(1.0)
    assert ios_matrix(tiny, tiny)[0, 0] == pytest.approx(1.0)
    empty = b([5, 5, 5, 5])
    assert iou_matrix(empty, empty)[0, 0] == 0.0 and ios_matrix(empty, empty)[0, 0] == 0.0
    for m in (iou_matrix(empty, tiny), ios_matrix(empty, tiny)):
        assert m.dtype == np.float64 and m[0, 0] == 0.0


def test_intersection_over_smaller_is_the_share_of_the_smaller_box() -> None:
    outer, inner = b([0, 0, 10, 10]), b([0, 0, 2, 2])
    assert ios_matrix(outer, inner)[0, 0] == pytest.approx(1.0)
    assert ios_matrix(outer, b([1, 1, 3, 5]))[0, 0] == pytest.approx(1.0)
    assert ios_matrix(b([0, 0, 4, 4]), b([2, 0, 6, 4]))[0, 0] == pytest.approx(0.5)


def test_gap_of_tall_and_wide_boxes_and_of_overlapping_ones() -> None:
    tall = b([0, 0, 10, 100])
    assert gap_matrix(tall, b([20, 0, 30, 100]))[0, 0] == pytest.approx(10.0)
    assert gap_matrix(b([0, 50, 10, 60]), b([25, 0, 35, 10]))[0, 0] == pytest.approx(40.0)
    assert gap_matrix(tall, b([5, 5, 50, 50]))[0, 0] == 0.0  # overlap: no negative gap


def test_nms_keeps_a_single_box() -> None:
    assert nms(b([0, 0, 10, 10]), np.array([0.9]), 0.5).tolist() == [0]


def test_nms_keeps_both_boxes_at_exactly_the_threshold() -> None:
    # IoU exactly 0.5 (100 / 200): only "above the threshold" suppresses, as cv2.dnn.NMSBoxes
    boxes = b([0, 0, 10, 10], [0, 0, 10, 20])
    assert iou_matrix(boxes[:1], boxes[1:])[0, 0] == 0.5
    assert sorted(nms(boxes, np.array([0.9, 0.8]), 0.5).tolist()) == [0, 1]


def test_nms_orders_equal_scores_by_input_order() -> None:
    rng = np.random.default_rng(0)
    scores = rng.choice([0.5, 0.7, 0.9], 60)
    boxes = np.array([[30.0 * i, 0, 30.0 * i + 20, 50] for i in range(60)])  # all apart
    kept = nms(boxes, scores, 0.5)
    assert kept.tolist() == np.argsort(-scores, kind="stable").tolist()


def test_merge_of_nothing_keeps_the_shapes() -> None:
    boxes, scores = merge_boxes(np.zeros((0, 4), np.float32), np.zeros(0, np.float32))
    assert boxes.shape == (0, 4) and scores.shape == (0,)


def test_merge_keeps_the_input_dtypes() -> None:
    boxes = b([0, 0, 10, 10], [10, 0, 20, 10], [50, 50, 60, 60]).astype(np.float32)
    merged, scores = merge_boxes(boxes, np.array([0.5, 0.9, 0.7], np.float32))
    assert merged.dtype == np.float32 and scores.dtype == np.float32


def test_merged_groups_come_best_score_first_and_ties_in_input_order() -> None:
    boxes = b(*[[30.0 * i, 0, 30.0 * i + 20, 50] for i in range(40)])  # 40 persons apart
    rng = np.random.default_rng(1)
    scores = rng.choice([0.5, 0.7, 0.9], 40)
    merged, best = merge_boxes(boxes, scores)
    assert best.tolist() == sorted(scores.tolist(), reverse=True)
    assert merged[:, 0].tolist() == boxes[np.argsort(-scores, kind="stable"), 0].tolist()


def test_touch_distance_is_inclusive_and_zero_still_merges_touching_boxes() -> None:
    touching = b([0, 0, 10, 10], [10, 0, 20, 10])  # gap exactly 0
    assert len(merge_boxes(touching, np.array([0.9, 0.8]), touch_px=0.0)[0]) == 1
    one_px = b([0, 0, 10, 10], [11, 0, 20, 10])  # gap exactly 1 px: the default touch_px
    assert len(merge_boxes(one_px, np.array([0.9, 0.8]))[0]) == 1
    apart = b([0, 0, 10, 10], [11.5, 0, 20, 10])  # 1.5 px: two persons side by side
    assert len(merge_boxes(apart, np.array([0.9, 0.8]))[0]) == 2


def test_merge_thresholds_are_strict_without_touch() -> None:
    half = b([0, 0, 10, 10], [0, 0, 10, 20])  # IoU exactly 0.5, IoS 1.0
    assert len(merge_boxes(half, np.array([0.9, 0.8]), iou_threshold=0.5, ios_threshold=1.0,
                           touch_px=-1)[0]) == 2
    assert len(merge_boxes(half, np.array([0.9, 0.8]), iou_threshold=0.49, ios_threshold=1.0,
                           touch_px=-1)[0]) == 1
    nested = b([0, 0, 10, 10], [0, 0, 10, 7])  # IoS exactly 1.0, IoU 0.7
    assert len(merge_boxes(nested, np.array([0.9, 0.8]), iou_threshold=0.9, ios_threshold=1.0,
                           touch_px=-1)[0]) == 2
    assert len(merge_boxes(nested, np.array([0.9, 0.8]), iou_threshold=0.7, ios_threshold=1.0,
                           touch_px=-1)[0]) == 2  # IoU 0.7 is not above 0.7 either


def test_merged_box_is_the_union_coordinate_by_coordinate() -> None:
    # x1 values larger than y1 values: a mix-up of the coordinates shows
    boxes = b([40, 5, 60, 30], [50, 10, 80, 25])
    merged, _ = merge_boxes(boxes, np.array([0.6, 0.9]))
    assert merged.tolist() == [[40.0, 5.0, 80.0, 30.0]]


def test_the_default_thresholds_without_touch_merge_strong_overlaps_only() -> None:
    overlap = b([0, 0, 10, 10], [2, 0, 12, 10])  # IoU 0.67 > the default 0.5
    assert len(merge_boxes(overlap, np.array([0.9, 0.8]), touch_px=-1)[0]) == 1
    weak = b([0, 0, 10, 10], [6, 0, 16, 10])  # IoU 0.25, IoS 0.4: two persons side by side
    assert len(merge_boxes(weak, np.array([0.9, 0.8]), touch_px=-1)[0]) == 2


def test_the_default_iou_rule_merges_just_above_one_half_and_not_below():
    """Equal boxes sliding apart, merging by touch off: at IoU 0.515 (overlap over the smaller
    box 0.68, below its 0.7 rule) only the default IoU threshold (0.5) merges them; at IoU 0.49
    (overlap 0.66) nothing does."""
    scores = np.array([0.9, 0.8])
    above = np.array([[0.0, 0.0, 100.0, 100.0], [32.0, 0.0, 132.0, 100.0]])
    below = np.array([[0.0, 0.0, 100.0, 100.0], [34.0, 0.0, 134.0, 100.0]])
    merged, _ = merge_boxes(above, scores, touch_px=-1)
    assert merged.tolist() == [[0.0, 0.0, 132.0, 100.0]]
    assert len(merge_boxes(below, scores, touch_px=-1)[0]) == 2
