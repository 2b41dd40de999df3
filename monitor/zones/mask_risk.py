"""How risky each mask zone is, judged by what a person standing there would look like.

The mask rule (``monitor.zones.masks``) suppresses a group of raw boxes only when it lies
wholly inside the mask grown by the detector's box error **and** its outline matches the
mask's own extent within that error. So a mask can hide a person only where a person's box can
have the mask's extent: a person standing at the mask's foot whose pixel height, for some
height in the zone file's ``person.height_range_m``, is the mask's height within twice the box
error. ``zones validate`` says for each mask and camera which of these it is:

* ``hides``: a person of some height in the range standing at the mask's foot has a box as tall
  and as wide as the mask's outline within the box error: the rule cannot tell them from the
  object (a warning, naming the protective or warning zones within a person's width: a missed
  STOP or SLOW; a note when no such zone is near);
* ``fits``: a whole person fits inside the grown mask there but cannot match its outline: kept
  (the rule reports the mask as unmatched);
* ``smaller``: smaller than any person there: ok;
* ``larger``: taller than any person there: it suppresses nothing unless its object fills it
  (draw it tight);
* ``unknown``: the camera has no 3D calibration (or the mask's foot never meets the floor):
  the person size there is unknown, so it is graded like ``hides``.

A person's box is taken as ``person.radius_m`` (side on) to ``2 * person.radius_m`` (the
person cylinder, facing the camera) wide; a person spreading their arms wider is not considered.
Floors (platforms) are not used: the person stands on the floor at the mask's foot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from monitor.zones.files import Cell
from monitor.zones.masks import ALERT_KINDS, grow_mask, raster, zone_regions_px

LEVELS = ("hides", "unknown", "fits", "larger", "smaller")
RISKY = frozenset({"hides", "unknown"})


def default_box_error_px(width: int, height: int) -> float:
    """One finest grid cell of the shipped tiny-YOLOv3 (stride 16 at a 416x416 letterbox) in
    pixels of a ``width`` x ``height`` frame: 25 px at 640x360, 49 px at 1280x720."""
    return 16.0 * max(width, height) / 416.0


@dataclass(frozen=True)
class MaskRisk:
    """One mask seen by one camera: its grade, what a person at its foot would look like
    (pixel width and height ranges, None when unknown), the mask's outline and grown size and
    the alert zones within a person's width of it ((kind, id), protective first)."""

    mask_id: str
    camera_id: str
    level: str
    extent_px: tuple[float, float]
    box_error_px: float
    heights_m: tuple[float, float]
    person_w_px: tuple[float, float] | None = None
    person_h_px: tuple[float, float] | None = None
    near: tuple[tuple[str, str], ...] = ()

    @property
    def grown_px(self) -> tuple[float, float]:
        return (self.extent_px[0] + 2 * self.box_error_px,
                self.extent_px[1] + 2 * self.box_error_px)

    @property
    def warning(self) -> bool:
        return self.level in RISKY

    @property
    def near_protective(self) -> bool:
        return any(kind == "protective" for kind, _ in self.near)

    def describe(self) -> str:
        """One line in plain words (``zones validate``)."""
        head = f"mask zone '{self.mask_id}' in camera '{self.camera_id}'"
        gw, gh = self.grown_px
        ew, eh = self.extent_px
        lo_m, hi_m = self.heights_m
        near = ""
        if self.near:
            near = "; near " + ", ".join(f"{k} zone '{z}'" for k, z in self.near)
        if self.person_h_px is None or self.person_w_px is None:
            return (f"{head}: a person's size at the mask is unknown (no 3D calibration, or its "
                    f"foot above the horizon): a person whose box is its outline ({ew:.0f}x"
                    f"{eh:.0f} px, box error {self.box_error_px:.0f} px) would be dropped as "
                    f"its object{near}; draw the mask tight around the object")
        (wl, wh), (hl, hh) = self.person_w_px, self.person_h_px
        person = (f"a {lo_m:g}-{hi_m:g} m person standing at its foot is {wl:.0f}-{wh:.0f} x "
                  f"{hl:.0f}-{hh:.0f} px; its outline is {ew:.0f}x{eh:.0f} px, grown by the box "
                  f"error {gw:.0f}x{gh:.0f} px")
        if self.level == "hides":
            return (f"{head} can hide a whole person ({person}): a person that size standing "
                    f"in line with the object is dropped as the object{near}")
        if self.level == "fits":
            return (f"{head}: a whole person fits inside it but cannot fill its outline "
                    f"({person}): such a person is kept, and so is its object unless it fills the "
                    "outline: ok")
        if self.level == "larger":
            return (f"{head} is larger than any person there ({person}): it hides no person, "
                    "and its object is seen as a person unless it fills the outline: ok")
        return f"{head} is smaller than any person there ({person}): ok"


def _person_px(cell: Cell, camera_id: str, foot_px: np.ndarray,
               ) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """((narrowest, widest), (lowest, highest)) box size in pixels of a person of the zone
    file's height range and radius standing with feet at any of ``foot_px`` (the camera's
    full-resolution pixels); None when unknown (no 3D calibration, or a foot that never meets
    the floor)."""
    model = cell.camera_models.get(camera_id)
    if model is None or not model.can_project_3d:
        return None
    person = cell.spec.person
    lo_m, hi_m = person.height_range_m
    floor, valid = model.pixel_to_floor(np.asarray(foot_px, float))
    if not valid.all():
        return None
    widths, heights = [], []
    for x, y in floor:
        px, front = model.project(np.array([[x, y, 0.0], [x, y, lo_m], [x, y, hi_m]]))
        if not front.all():
            return None
        per_m = (px[0, 1] - px[2, 1]) / hi_m
        heights += [px[0, 1] - px[1, 1], px[0, 1] - px[2, 1]]
        widths += [person.radius_m * per_m, 2 * person.radius_m * per_m]
    return (float(min(widths)), float(max(widths))), (float(min(heights)), float(max(heights)))


def _overlaps(lo: float, hi: float, target: float, tolerance: float) -> bool:
    return hi >= target - tolerance and lo <= target + tolerance


def mask_risks(cell: Cell, box_error_px: float | None = None) -> list[MaskRisk]:
    """Every enabled mask zone in every camera that sees it, graded (module docstring).
    ``box_error_px``: the detector's box error at the camera's full resolution (default: one
    grid cell of the shipped model)."""
    out: list[MaskRisk] = []
    lo_m, hi_m = cell.spec.person.height_range_m
    for camera_id, cam in cell.cameras.items():
        masks = zone_regions_px(cell, camera_id, ("mask",))
        if not masks:
            continue
        alerts = zone_regions_px(cell, camera_id, ALERT_KINDS)
        err = (box_error_px if box_error_px is not None
               else default_box_error_px(cam.width, cam.height))
        for mz, poly in masks:
            x1, y1 = poly.min(axis=0)
            x2, y2 = poly.max(axis=0)
            ew, eh = float(x2 - x1), float(y2 - y1)
            cx = (x1 + x2) / 2
            # the rule matches every edge within err: the feet anywhere in that band
            size = _person_px(cell, camera_id, np.array([[cx, y2 - err], [cx, y2],
                                                         [cx, y2 + err]]))
            pw = ph = None
            if size is None:
                level = "unknown"
            else:
                pw, ph = size
                if _overlaps(*ph, eh, 2 * err) and _overlaps(*pw, ew, 2 * err):
                    level = "hides"
                elif ph[0] <= eh + 2 * err and pw[0] <= ew + 2 * err:
                    level = "fits" if ph[1] >= eh - 2 * err else "larger"
                else:
                    level = "smaller"
            reach = pw[1] if pw is not None else cam.width / 10
            region = grow_mask(raster([poly], cam.width, cam.height), max(reach, err))
            near = [(az.kind, az.id) for az, apoly in alerts
                    if (region & raster([apoly], cam.width, cam.height)).any()]
            near.sort(key=lambda k: ALERT_KINDS.index(k[0]))
            out.append(MaskRisk(mz.id, camera_id, level, (ew, eh), err, (lo_m, hi_m), pw, ph,
                                tuple(dict.fromkeys(near))))
    return out


def mask_risk_lines(cell: Cell, box_error_px: float | None = None
                    ) -> list[tuple[str, str]]:
    """(grade, line) per mask and camera for ``zones validate``, riskiest first: ``warning``
    for a mask that can hide a person within a person's width of a protective zone (a missed
    STOP) or a warning zone (a missed SLOW), ``note`` for one that can hide a person elsewhere,
    ``ok`` for the rest."""
    out = []
    for r in sorted(mask_risks(cell, box_error_px),
                    key=lambda r: (not r.warning, not r.near_protective, not r.near)):
        if not r.warning:
            out.append(("ok", r.describe()))
        elif r.near:
            miss = "a missed STOP" if r.near_protective else "a missed SLOW"
            out.append(("warning", f"{r.describe()} ({miss})"))
        else:
            out.append(("note", r.describe()))
    return out
