"""What the tracker remembers of one person between frames (``monitor.tracking.tracks``):
the last box and sighting, motion, the zones, whether lost, and what a snapshot hands out."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from monitor.tracking.track_types import Track
from monitor.tracking.whereabouts import HeldZone


@dataclass
class TrackRecord:
    track_id: int
    box: np.ndarray  # (4,) float64
    last_seen: float
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    floor: np.ndarray | None = None
    floor_velocity: np.ndarray | None = None
    zones: tuple[HeldZone, ...] = ()
    lost: bool = False
    was: int | None = None  # the lost track this one perhaps is (a guess; see reidentified)
    seen_as: int | None = None  # a new track that perhaps is this lost one
    left_view: bool = False
    # (time, box height) of the last ``TALL_WINDOW_S``: a person walking behind a wall is
    # seen smaller frame by frame, and at 15 fps the last box may be a head only; the area
    # grows at the pace of the person's full height, not of that sliver
    heights: list[tuple[float, float]] = field(default_factory=list)
    feet_bottom: float = math.nan  # a cut-off box: the lowest row its hidden feet may be on
    byte_id: int = -1  # the last sighting's ByteTrack id (-1: none)

    def tall_px(self) -> float:
        """The tallest box height of the last ``TALL_WINDOW_S`` seconds it was seen."""
        return max((h for _, h in self.heights), default=float(self.box[3] - self.box[1]))

    def snapshot(self, held: tuple[HeldZone, ...]) -> Track:
        floor = None if self.floor is None else (float(self.floor[0]), float(self.floor[1]))
        fvel = None if self.floor_velocity is None else (float(self.floor_velocity[0]),
                                                        float(self.floor_velocity[1]))
        return Track(self.track_id, _box_tuple(self.box), self.last_seen,
                     (float(self.velocity[0]), float(self.velocity[1])), floor, fvel,
                     self.zones, self.lost, held, self.was, self.left_view)

    def label(self) -> str:
        """``person 6``, or ``person 6 (was person 1?)`` when re-identified by a guess."""
        return f"person {self.track_id}" + ("" if self.was is None else
                                             f" (was person {self.was}?)")


TALL_WINDOW_S = 1.0


def _box_tuple(box: np.ndarray) -> tuple[float, float, float, float]:
    return (float(box[0]), float(box[1]), float(box[2]), float(box[3]))
