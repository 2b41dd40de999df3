"""Raised and sunken floor regions: where a sight line may put a person's feet besides z = 0.

A *floor region* is a horizontal standing surface at ``height_m`` over a floor polygon (a
platform, a mezzanine, a pit's floor). A pixel's viewing ray meets the plane z = height inside
the polygon at most once per region, so a foot pixel has one candidate position on the cell
floor and one on each region its ray meets there: the placement keeps all of them
(``monitor.geometry.occlusion``). Pure functions, metres, z up.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monitor.geometry.polygons import points_in_polygon

# A hit this close to a region's outline counts as on it: a person standing at a platform's
# edge has feet (and a box bottom) reaching past the edge (metres).
EDGE_MARGIN_M = 0.3


@dataclass(frozen=True, eq=False)
class FloorRegion:
    """One standing surface: ``points_m`` (K, 2) floor polygon, at ``height_m`` above z = 0."""

    id: str
    points_m: np.ndarray
    height_m: float

    @classmethod
    def of(cls, region_id: str, points_m: Sequence[Sequence[float]], height_m: float
           ) -> FloorRegion:
        return cls(region_id, np.asarray(points_m, float).reshape(-1, 2), float(height_m))


def near_polygon(points_xy: np.ndarray, polygon: np.ndarray, margin_m: float) -> np.ndarray:
    """(N,) bool: points inside the polygon or within ``margin_m`` of its outline."""
    p = np.asarray(points_xy, float).reshape(-1, 2)
    out = points_in_polygon(p, polygon)
    if margin_m <= 0 or not len(p):
        return out
    a = polygon
    b = np.roll(polygon, -1, axis=0)
    d = b - a  # (K, 2)
    den = np.maximum(np.einsum("ij,ij->i", d, d), 1e-18)
    t = np.clip(np.einsum("nkj,kj->nk", p[:, None, :] - a[None], d) / den, 0.0, 1.0)
    nearest = a[None] + t[..., None] * d[None]
    dist = np.hypot(*(p[:, None, :] - nearest).transpose(2, 0, 1)).min(axis=1)
    return out | (dist <= margin_m)


def plane_hits(centre_m: np.ndarray, rays: np.ndarray, regions: Sequence[FloorRegion],
               above_m: float = 0.0, margin_m: float = EDGE_MARGIN_M
               ) -> tuple[np.ndarray, np.ndarray]:
    """Where each viewing ray meets each region's surface raised by ``above_m`` (a head
    ``above_m`` over the surface), with the point below it on the region.

    ``centre_m`` (3,) camera centre, ``rays`` (N, 3) unit directions. Returns the floor
    points (N, R, 2) under the hits and (N, R) bool: the ray meets that plane in front of the
    camera and the point lies on the region (or within ``margin_m`` of its outline)."""
    d = np.asarray(rays, float).reshape(-1, 3)
    n, r = len(d), len(regions)
    xy = np.zeros((n, r, 2))
    ok = np.zeros((n, r), dtype=bool)
    dz = d[:, 2]
    steep = np.abs(dz) > 1e-9
    for k, region in enumerate(regions):
        s = np.where(steep, (region.height_m + above_m - centre_m[2])
                     / np.where(steep, dz, 1.0), -1.0)
        xy[:, k] = centre_m[:2] + s[:, None] * d[:, :2]
        front = s > 0
        if front.any():
            ok[front, k] = near_polygon(xy[front, k], region.points_m, margin_m)
    return xy, ok
