"""The walk test finds undeclared occluders: where the walker's box was cut off at the bottom by
a fixture the zone file does not declare.

A box whose lower edge lies on a horizontal edge of the camera's commissioning reference
(``monitor.geometry.edges``) that no declared occluder or floor region explains was cut off by
something the zone file leaves out: a bench, a crate, a cabinet front. The monitor places such
a person correctly (a range from the box towards the camera, docs/occlusion.md), but the floor
behind that fixture counts as seen where it is not (a crouching person there is hidden), so
the walk lists the floor cells along each such range, per zone, drawn as "feet hidden here:
declare an occluder"; the walk does not pass while any lies in a protective zone.

Pure functions over the prepared zones and boxes.
"""

from __future__ import annotations

from collections.abc import Iterable

import cv2
import numpy as np

from monitor.geometry.occlusion import EDGE_TOLERANCE_PX, on_reference_edge
from monitor.zones.check import placement

FEET_HIDDEN_TEXT = "feet hidden here: declare an occluder"
FEET_HIDDEN_BGR = (200, 40, 200)
RANGE_SAMPLES = 7  # floor points along each cut-off box's range


def undeclared_cuts(prepared, camera_id: str, boxes_px: np.ndarray,
                    band_px: tuple[float, float]) -> np.ndarray:
    """(M, 2) floor points (metres) along the ranges of the boxes cut off by an edge of the
    reference that no declared occluder or floor region explains (none without a reference
    or a calibration)."""
    boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
    edges = prepared.reference_edges.get(camera_id) if prepared is not None else None
    if edges is None or not len(boxes):
        return np.zeros((0, 2))
    cut = on_reference_edge(boxes, edges, float(max(band_px)))
    declared = prepared.occluder_columns.get(camera_id)
    if declared is not None:
        u = (boxes[:, 0] + boxes[:, 2]) * 0.5
        reach = max(EDGE_TOLERANCE_PX, float(max(band_px)))
        cut &= ~declared.meets(u, boxes[:, 3], boxes[:, 3] + reach)
    if not cut.any():
        return np.zeros((0, 2))
    place = placement(prepared, camera_id, boxes[cut], band_px)
    if place is None:
        return np.zeros((0, 2))
    t = np.linspace(0.0, 1.0, RANGE_SAMPLES)[None, :, None]
    near, far = place.near_m[place.located], place.far_m[place.located]
    return (near[:, None, :] + t * (far - near)[:, None, :]).reshape(-1, 2)


def hidden_feet_doubts(walk: dict) -> list[str]:
    """The report's doubts of a walk result (``walk.json``): protective zones with cells where
    the walker's feet were hidden by an undeclared fixture."""
    out = []
    for z in walk.get("zones", []):
        cells = z.get("feet_hidden") or []
        if z.get("kind") == "protective" and cells:
            out.append(f"zone {z['zone_id']}: {len(cells)} floor cells where the walker's feet "
                       f"were hidden by something the zone file does not declare "
                       f"({FEET_HIDDEN_TEXT}): the walk does not pass")
    return out


def walk_passes_hidden_feet(zones: Iterable) -> bool:
    """No protective zone of a walk (``ZoneWalk``s) has cells with the walker's feet hidden."""
    return not any(z.kind == "protective" and z.feet_hidden for z in zones)


def draw_feet_hidden(img: np.ndarray, cells: Iterable[tuple[np.ndarray, np.ndarray]]) -> None:
    """Cross out each cell (its top-left and bottom-right pixel corners) in
    ``FEET_HIDDEN_BGR`` and say once what it means."""
    first = None
    for a, b in cells:
        p1 = (int(a[0]), int(a[1]))
        p2 = (int(b[0]), int(b[1]))
        cv2.rectangle(img, p1, p2, FEET_HIDDEN_BGR, 2)
        cv2.line(img, p1, p2, FEET_HIDDEN_BGR, 1)
        cv2.line(img, (p1[0], p2[1]), (p2[0], p1[1]), FEET_HIDDEN_BGR, 1)
        first = first or p1
    if first is not None:
        cv2.putText(img, FEET_HIDDEN_TEXT, (first[0], max(12, first[1] - 4)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.4, FEET_HIDDEN_BGR, 1, cv2.LINE_AA)
