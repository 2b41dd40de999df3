"""Merging two zone answers towards danger (several cameras, or two placements of one person):
the worse of both, field by field. Pure function; cases from mutation testing of
monitor/zones/check.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monitor.config import demo_cell_path
from monitor.types import ZoneHit, ZoneReport
from monitor.zones import check_persons, load_cell, merge_towards_danger


def hit(zone="z", person=0, distance=None, track=None, lost=False, scale=0.0) -> ZoneHit:
    return ZoneHit(zone, "protective", person, scale, distance, track, lost)


@pytest.mark.parametrize(("a", "b", "merged"), [
    (0.5, 0.8, 0.5), (0.8, 0.5, 0.5), (None, 0.7, 0.7), (0.7, None, 0.7), (None, None, None),
])
def test_the_smaller_separation_speed_scale_wins(a, b, merged):
    m = merge_towards_danger(ZoneReport(separation_speed_scale=a),
                             ZoneReport(separation_speed_scale=b))
    assert m.separation_speed_scale == merged


@pytest.mark.parametrize("order", ["nan-first", "nan-second"])
def test_an_unknown_speed_scale_wins_over_any_number(order):
    pair = [ZoneReport(separation_speed_scale=math.nan), ZoneReport(separation_speed_scale=0.3)]
    if order == "nan-second":
        pair.reverse()
    assert math.isnan(merge_towards_danger(*pair).separation_speed_scale)


def test_separations_masks_and_config_hash():
    a = ZoneReport(tool_separation_m=1.2, required_separation_m=0.9, masked=(1, 2),
                   config_hash="abc")
    b = ZoneReport(tool_separation_m=0.7, required_separation_m=1.4, masked=(2, 3),
                   config_hash="abc")
    m = merge_towards_danger(a, b)
    assert (m.tool_separation_m, m.required_separation_m, m.masked, m.config_hash) == \
        (0.7, 1.4, (2,), "abc")


def test_one_hit_per_zone_and_person_the_nearer_distance_kept():
    m = merge_towards_danger(ZoneReport(hits=(hit(distance=0.4, scale=0.1),)),
                             ZoneReport(hits=(hit(distance=0.2, scale=0.2),)))
    assert m.hits == (hit(distance=0.2, scale=0.2),)
    # equal distances: the first answer stays
    m = merge_towards_danger(ZoneReport(hits=(hit(distance=0.3, scale=0.1),)),
                             ZoneReport(hits=(hit(distance=0.3, scale=0.2),)))
    assert m.hits == (hit(distance=0.3, scale=0.1),)


def test_an_unknown_distance_is_worse_than_a_known_one():
    # an image-zone hit (no distance) is kept; a known distance does not replace it
    m = merge_towards_danger(ZoneReport(hits=(hit(distance=None, scale=0.1),)),
                             ZoneReport(hits=(hit(distance=0.0, scale=0.2),)))
    assert m.hits == (hit(distance=None, scale=0.1),)
    m = merge_towards_danger(ZoneReport(hits=(hit(distance=0.3, scale=0.1),)),
                             ZoneReport(hits=(hit(distance=None, scale=0.2),)))
    assert m.hits == (hit(distance=None, scale=0.2),)


def test_a_lost_persons_hold_wins_over_a_seen_hit_in_either_order():
    seen, held = hit(track=3, distance=0.0), hit(track=3, lost=True)
    assert merge_towards_danger(ZoneReport(hits=(held,)), ZoneReport(hits=(seen,))).hits == \
        (held,)
    assert merge_towards_danger(ZoneReport(hits=(seen,)), ZoneReport(hits=(held,))).hits == \
        (held,)


def test_different_zones_persons_and_tracks_are_all_kept():
    hits = (hit("a"), hit("b"), hit("a", person=1), hit("a", track=7))
    assert set(merge_towards_danger(ZoneReport(hits=hits[:2]),
                                    ZoneReport(hits=hits[2:])).hits) == set(hits)


def test_an_explicit_foot_band_is_used():
    """A box whose bottom ends 20 px below the demo's image protective zone: with a foot band
    of 49 px the feet may be inside it (STOP), with none they are not."""
    cell = load_cell(demo_cell_path())
    box = np.array([[600.0, 300.0, 680.0, 552.0]])
    banded = check_persons(cell, "cam0", box, foot_band_px=(0.0, 49.0))
    tight = check_persons(cell, "cam0", box, foot_band_px=(0.0, 0.0))
    assert "cam0-protective" in {h.zone_id for h in banded.hits}
    assert "cam0-protective" not in {h.zone_id for h in tight.hits}
