"""Where a camera can see a person: the foot positions of its image in which a person standing
(or crouching) would show to it, so that "no box there" means "nobody there".

A foot position is *hidden* from a camera when

* the camera is calibrated and less than the share of a person the detector needs
  (``person.visible_fraction``, measured beside the model's operating envelope) of the smallest
  posture the monitor must protect (``person.crouching_height_m``, a person crouching, or the
  shortest standing height when lower: ``PersonSpec.smallest_height_m``) standing on the floor
  point under it is in view: the sight lines to the rest pass through a declared occluder or
  the robot base (``coverage.figure_visible``; the same test ``zones validate``'s coverage
  check uses). A head sliver over a bench is not a person the detector finds. A person whose
  feet are in the image but whose head is cut by its border counts as seen (the detector finds
  cut persons; one moving out of the view has left it); or
* it lies in a mask zone's image region, grown by the detector's box error (a person there is
  suppressed with the masked object: ``monitor.zones.masks``).

Floor points the camera cannot place (at or above its horizon) are not hidden: nobody stands
there. An uncalibrated camera knows no occluders: only its masks hide. The lost persons' areas
(``monitor.tracking.whereabouts``) never count a hidden foot position as seen free.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import cv2
import numpy as np

from monitor import geometry as geo
from monitor.geometry.occlusion import standable
from monitor.zones.coverage import figure_visible, occluders_contain
from monitor.zones.schema import CellSpec


def hidden_feet(centres_px: np.ndarray, image_size: tuple[int, int],
                model: geo.CameraModel | None, spec: CellSpec | None,
                meshes: Mapping[str, tuple[np.ndarray, np.ndarray]],
                masks: Sequence[np.ndarray] = (), mask_margin_px: float = 0.0,
                fraction: float | None = None) -> np.ndarray:
    """(N,) bool: the foot positions ``centres_px`` (pixels of an image of ``image_size``)
    at which no person could be seen by the camera (module docstring). ``fraction``: the
    visible share the detector needs (None: the zone file's ``person.visible_fraction``)."""
    pts = np.asarray(centres_px, np.float64).reshape(-1, 2)
    hidden = np.zeros(len(pts), dtype=bool)
    if model is not None and spec is not None and len(pts):
        scale = np.array([model.width / image_size[0], model.height / image_size[1]])
        xy, located = model.pixel_to_floor(pts * scale)
        if located.any():
            occluders = spec.occluder_zones()
            contain = occluders_contain(occluders, meshes)
            p = spec.person
            feet = xy[located]
            seen = figure_visible(model, feet, p.smallest_height_m,
                                  p.needed_fraction if fraction is None else fraction,
                                  p.radius_m, contain)
            # nobody stands inside a bench or the robot base: nothing hides there
            hidden[located] = ~seen & standable(occluders, meshes, feet)
    for poly in masks:
        p = np.asarray(poly, np.float32).reshape(-1, 1, 2)
        for i, (x, y) in enumerate(pts):
            if not hidden[i] and cv2.pointPolygonTest(p, (float(x), float(y)), True) \
                    >= -mask_margin_px:
                hidden[i] = True
    return hidden
