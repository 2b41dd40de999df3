"""Floor regions of a zone file (``floors:``): the checks a validated file must pass.

A floor region is a raised or sunken standing surface (platform, mezzanine, pit floor) at
``height_m`` over a floor polygon; placement uses it (``monitor.geometry.floors``,
docs/occlusion.md). The schema (``monitor.zones.schema.FloorSpec``) checks the types and
bounds; here: the polygon, unique ids, and a region that changes nothing.
"""

from __future__ import annotations

from monitor import geometry as geo
from monitor.zones.schema import CellSpec


def check_floors(spec: CellSpec) -> list[str]:
    """One message per fault of the file's floor regions (empty when all are sound)."""
    out: list[str] = []
    seen: set[str] = set()
    for f in spec.floors:
        if f.id in seen:
            out.append(f"floor '{f.id}': id used twice (floor ids must be unique)")
        seen.add(f.id)
        fault = geo.polygon_fault(f.points_m)
        if fault:
            out.append(f"floor '{f.id}': points_m: {fault}")
        if f.height_m == 0.0:
            out.append(f"floor '{f.id}': height_m 0 is the cell floor itself (a platform is "
                       "above it, a pit below: give its height in metres)")
    return out
