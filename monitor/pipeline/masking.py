"""Mask zones on the detector's raw boxes (docs/masks.md): each camera's mask rule at its frame
size, the detector's pre-merge filter built from it, and the whole boxes of persons who touched
a masked object added back to the frame's persons (``with_touching``, pure)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from monitor.detector import Detector
from monitor.types import FrameInfo, Persons
from monitor.zones import Cell
from monitor.zones.masks import MaskRule


@dataclass
class MaskTally:
    """What one frame's mask rule did: raw boxes dropped, and the whole boxes of groups that
    touched a mask (``MaskCheck.touching``)."""

    masked: int = 0
    touching: list[np.ndarray] = field(default_factory=list)


def with_touching(persons: Persons, touching: list[np.ndarray]) -> Persons:
    """``persons`` plus the whole box of every person who touched a masked object.

    The mask rule drops such a person's boxes inside the mask, so their merged box is only the
    part outside it: narrower than the person and placed up to a grid cell wrong. The whole
    group's box (person and object) is checked too, and the zone answer is the worse of the
    two: a box including the object is at worst a false STOP, never a missed one. Each extra
    box gets the best score of the person boxes it overlaps (the person's own)."""
    if not touching:
        return persons
    boxes = persons.boxes_px.astype(np.float64)
    extra_boxes, extra_scores = [], []
    for t in touching:
        if len(boxes) and (np.abs(boxes - t).max(axis=1) <= 1.0).any():
            continue  # merging already gave this box
        overlap = ((np.minimum(boxes[:, 2], t[2]) > np.maximum(boxes[:, 0], t[0]))
                   & (np.minimum(boxes[:, 3], t[3]) > np.maximum(boxes[:, 1], t[1])))
        score = float(persons.scores[overlap].max()) if overlap.any() else \
            float(persons.scores.max()) if len(persons) else 1.0
        extra_boxes.append(t)
        extra_scores.append(score)
    if not extra_boxes:
        return persons
    return Persons(np.concatenate([persons.boxes_px, np.array(extra_boxes, np.float32)]),
                   np.concatenate([persons.scores, np.array(extra_scores, np.float32)]),
                   persons.frame)


class MaskRules:
    """The mask rule of each camera at each frame size, built once per zone set (a zone swap
    makes a new ``MaskRules``)."""

    def __init__(self, cell: Cell | None, detector: Detector) -> None:
        self.cell = cell
        self.detector = detector
        self._rules: dict[tuple[str, int, int], MaskRule] = {}

    def rule(self, frame: FrameInfo) -> MaskRule | None:
        """The mask rule of the frame's camera at its size (None: no mask zones)."""
        if self.cell is None:
            return None
        key = (frame.camera_id, frame.width, frame.height)
        if key not in self._rules:
            margin = self.detector.foot_uncertainty_px(frame.width, frame.height)
            self._rules[key] = MaskRule.for_camera(self.cell, frame.camera_id, frame.width,
                                                   frame.height, margin)
        rule = self._rules[key]
        return rule if rule.active else None

    def pre_merge(self, frame: FrameInfo, tally: MaskTally
                  ) -> Callable[[np.ndarray], np.ndarray] | None:
        """The camera's mask rule as the detector's pre-merge filter (None: no masks); counts
        the raw boxes it drops and keeps the whole boxes of groups touching a mask in
        ``tally``."""
        rule = self.rule(frame)
        if rule is None:
            return None

        def pre_merge(boxes: np.ndarray) -> np.ndarray:
            check = rule.check(boxes)
            tally.masked += int(len(check.keep) - check.keep.sum())
            tally.touching.extend(check.touching)
            return check.keep

        return pre_merge
