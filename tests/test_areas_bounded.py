"""Lost persons' areas that do not spread through a busy scene (issue 46, docs/tracking.md,
"Where a lost person could be"): a fresh loss inside an old person's area leaves the old
area its own bounded life, and a person swallowed by a passer-by's box walks on at their own
depth, not at the passer-by's feet. Each with the attack it must still hold against."""

from __future__ import annotations

import numpy as np

from monitor import zones as zn
from monitor.tracking.whereabouts import Whereabouts
from tests.test_tracks import H, Run, W, held, person

# a protective image zone in the lower half of the picture, near the camera (as the street
# scene's zone, drawn on the floor in front of the robot)
NEAR = zn.parse_cell({
    "version": 1, "name": "near",
    "cameras": [{"id": "cam0", "width": W, "height": H}],
    "zones": [{"id": "stop", "kind": "protective", "shape": "polygon", "camera": "cam0",
               "points_px": [[500, 450], [800, 450], [800, 700], [500, 700]]}],
})


def _bounded(where: Whereabouts, now: float, frames: int, dt: float = 0.1) -> list:
    """Frames with nobody seen and nothing seen free (a clear time longer than the run)."""
    ended = []
    for k in range(1, frames + 1):
        where.update(now + k * dt, np.zeros((0, 4)), True, 100.0, None)
        ended += [(a.track_id, rule) for a, rule in where.take_ended()]
    return ended


def test_a_fresh_loss_inside_an_old_area_leaves_the_old_area_its_bounded_life():
    """Person 1's area (a tall box, grown for most of its bounded life) holds a fresh loss,
    person 2, inside it. Joined, the union lived as long as person 2's loss: in a busy scene
    a flicker a second kept one person's area alive for ever (street-polygons-5fps: person 6
    lost at 18.2 s absorbed 22 younger losses and held the zone to the end). Now person 1's
    area ends at its own bounded life and person 2's lives on (the attack: a person lost just
    now is never released by an older loss's bounded life)."""
    where = Whereabouts()
    where.view(W, H)
    where.lose(1, np.array(person(650, bottom=650, h=500, w=300)), 0.0)
    where.update(0.0, np.zeros((0, 4)), True, 100.0, None)
    old = where.areas[1]
    old.age_s = where.life_s(old) - 0.25  # a quarter second of its life left
    where.lose(2, np.array(person(650, bottom=640, h=200, w=60)), 0.0)
    assert not (where.areas[2].cells & ~old.cells).any()  # nested in person 1's area
    ended = _bounded(where, 0.0, 5)
    assert ended == [(1, "bounded life")]
    assert 2 in where.areas and where.areas[2].cells.any()


def test_a_fresh_loss_that_covers_an_old_area_takes_it_in():
    """The other nesting: person 1's old area lies inside the fresh loss's larger one. Joined
    (the union is the fresh loss's cells, named by the longest lost), it keeps the fresh
    loss's life: person 1's cells end no earlier than alone."""
    where = Whereabouts()
    where.view(W, H)
    where.lose(1, np.array(person(650, bottom=640, h=200, w=60)), 0.0)
    where.update(0.0, np.zeros((0, 4)), True, 100.0, None)
    where.areas[1].age_s = where.life_s(where.areas[1]) - 0.25
    where.lose(2, np.array(person(650, bottom=650, h=500, w=300)), 0.0)
    assert _bounded(where, 0.0, 5) == []
    (area,) = where.areas.values()
    assert area.track_id == 1 and area.merged == (2,) and area.age_s < 1.0


def test_a_lost_persons_area_and_a_place_a_merged_track_stood_stay_apart():
    """A place a merged track stood (``behind``: it does not walk, no sighting ends it) and
    a lost person's area (it walks) that nest are not joined: the union would take one
    rule for both (a walker's area that stops walking, or a merged place a sighting ends)."""
    where = Whereabouts()
    where.view(W, H)
    where.lose(1, np.array(person(650, bottom=650, h=500, w=300)), 0.0)
    where.lose(2, np.array(person(650, bottom=640, h=200, w=60)), 0.0, behind=True)
    where.update(0.0, np.zeros((0, 4)), True, 100.0, None)
    assert set(where.areas) == {1, 2}
    assert where.areas[2].behind and not where.areas[1].behind


def _swallowed_then_carried(b_box: list[float], a_bottom: float, a_h: float):
    """B stands still (``b_box``) while A, nearer the camera (bottom ``a_bottom``, height
    ``a_h``), walks right from x = 250 at 50 px a frame (10 fps); B's box is not detected
    while A's box covers it (hidden by A), and B stays hidden behind A from then on. Yields
    A's centre and the update of each frame after B was swallowed."""
    run = Run(fps=10.0, cell=NEAR)
    bx = (b_box[0] + b_box[2]) / 2
    x = 250.0
    b_id = None
    swallowed = False
    while x < 1050:
        a = person(x, bottom=a_bottom, h=a_h, w=160)
        covered = a[0] <= b_box[0] + 20 and a[2] >= b_box[2] - 20
        swallowed = swallowed or covered
        boxes = [a] if swallowed else [a, b_box]
        upd = run.frame(*boxes)
        if b_id is None:
            b_id = upd.track_ids[1]
        if swallowed:
            yield x, bx, b_id, upd, run
        x += 50


def test_a_person_swallowed_far_behind_a_passer_by_walks_on_at_their_own_depth():
    """B stands 400 px up the picture (far behind), A walks across in front of the zone
    (feet below it) and swallows B's box. B may walk on hidden behind A, but at B's own
    depth: A's feet band (which covers the zone behind A in the picture) is no place B can
    reach in that time. Before, the area took the cells under A's feet band and held the
    zone while A crossed in front of it (street-polygons-5fps: a person lost on the far lane
    held the zone while passers-by crossed the near lane)."""
    held_stop = []
    for x, _, b, upd, _run in _swallowed_then_carried(person(640, bottom=150, h=90, w=40),
                                                        a_bottom=712, a_h=640):
        held_stop += [x] if ("stop", b) in held(upd) else []
        if x > 900:
            break
    assert held_stop == []


def test_a_person_right_behind_a_passer_by_walks_with_them_into_the_zone_held():
    """The attack: B stands right behind A's path (feet 60 px above A's, inside the zone's
    rows), A swallows B's box and walks right across the zone, B hidden behind A all the way.
    B's area follows A's box at B's depth, into the zone: held while A is over it."""
    held_at = []
    for x, _, b, upd, _run in _swallowed_then_carried(person(420, bottom=652, h=560, w=80),
                                                        a_bottom=712, a_h=640):
        if 600 <= x <= 750:
            held_at.append(("stop", b) in held(upd))
    assert held_at and all(held_at), held_at
