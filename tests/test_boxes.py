import cv2
import numpy as np
import pytest

from monitor.geometry import boxes as B


def _random_boxes(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    xy = rng.uniform(0, 300, size=(n, 2))
    wh = rng.uniform(5, 120, size=(n, 2))
    return np.hstack([xy, xy + wh]).astype(np.float32), rng.uniform(0.1, 1, n).astype(np.float32)


@pytest.mark.parametrize("seed", range(20))
@pytest.mark.parametrize("iou", [0.3, 0.45, 0.7])
def test_nms_keeps_the_same_set_as_opencv(seed: int, iou: float) -> None:
    rng = np.random.default_rng(seed)
    boxes, scores = _random_boxes(rng, int(rng.integers(1, 80)))
    ours = set(B.nms(boxes, scores, iou).tolist())
    xywh = np.hstack([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]])
    theirs = cv2.dnn.NMSBoxes(xywh.tolist(), scores.tolist(), 0.0, iou)
    assert ours == set(np.asarray(theirs).reshape(-1).tolist())


def test_nms_of_nothing_is_empty() -> None:
    assert len(B.nms(np.zeros((0, 4)), np.zeros(0), 0.5)) == 0


def test_a_chain_of_overlapping_boxes_becomes_one_union_box() -> None:
    boxes = np.array([[0, 0, 10, 10], [8, 0, 18, 10], [16, 0, 26, 10], [24, 2, 34, 12]], float)
    scores = np.array([0.6, 0.9, 0.7, 0.8])
    merged, best = B.merge_boxes(boxes, scores, touch_px=-1, iou_threshold=0.05)
    np.testing.assert_allclose(merged, [[0, 0, 34, 12]])
    np.testing.assert_allclose(best, [0.9])


def test_two_separate_people_stay_two() -> None:
    boxes = np.array([[0, 0, 40, 100], [60, 0, 100, 100]], float)
    merged, _ = B.merge_boxes(boxes, np.array([0.9, 0.8]))
    assert len(merged) == 2


def test_a_box_inside_another_merges_by_intersection_over_smaller() -> None:
    # the seeds' case: a second, smaller box over the same person
    boxes = np.array([[0, 0, 40, 100], [5, 10, 35, 60]], float)
    merged, best = B.merge_boxes(boxes, np.array([0.7, 0.9]), touch_px=-1)
    np.testing.assert_allclose(merged, [[0, 0, 40, 100]])
    assert best[0] == pytest.approx(0.9)


def test_grid_cells_touching_along_an_edge_or_corner_merge() -> None:
    cells = np.array([[0, 0, 16, 16], [16, 0, 32, 16], [32, 16, 48, 32], [80, 80, 96, 96]], float)
    merged, _ = B.merge_boxes(cells, np.ones(4), touch_px=0.5)
    assert sorted(map(tuple, merged.tolist())) == [(0, 0, 48, 32), (80, 80, 96, 96)]


def test_connected_groups_labels_components() -> None:
    adj = np.zeros((5, 5), bool)
    for a, b in [(0, 3), (3, 4)]:
        adj[a, b] = adj[b, a] = True
    labels = B.connected_groups(adj)
    assert labels[0] == labels[3] == labels[4]
    assert len({labels[0], labels[1], labels[2]}) == 3
