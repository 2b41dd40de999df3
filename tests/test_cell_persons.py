"""One person id across the cameras of a cell (monitor/tracking/cell_persons.py): the real tracker
of each camera, with calibrations given as pixel -> floor functions."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from monitor.config import parse_config
from monitor.errors import ConfigError
from monitor.policy.causes import frame_causes
from monitor.tracking.cell_persons import CellPersons, CellPersonsConfig
from monitor.tracking.tracks import PersonTracker
from monitor.types import FrameInfo, Persons, ZoneHit, ZoneReport
from monitor.zones.check import merge_towards_danger

SCALE = 100.0  # px per metre of both test calibrations


def calibration(offset_m: tuple[float, float]):
    """A camera whose pixel (u, v) lies at floor (u, v) / 100 + offset: two cameras with other
    offsets see one floor point at different pixels."""
    off = np.array(offset_m)

    def to_floor(px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(px, np.float64) / SCALE + off, np.ones(len(px), bool)
    return to_floor


# cam1 sees the floor 2 m further along x: floor (3, 5) is cam0 (300, 500), cam1 (100, 500)
OFFSETS = {"cam0": (0.0, 0.0), "cam1": (2.0, 0.0)}


class Cell:
    """Two cameras, their trackers and the cell persons, fed person floor positions."""

    def __init__(self, calibrated=("cam0", "cam1"), config: CellPersonsConfig | None = None):
        self.trackers = {cid: PersonTracker(to_floor=calibration(OFFSETS[cid])
                                            if cid in calibrated else None)
                         for cid in OFFSETS}
        self.persons = CellPersons(tuple(OFFSETS), config or CellPersonsConfig())
        self.seq = 0

    def see(self, cam: str, t: float, *floor_m: tuple[float, float],
            hits: tuple[ZoneHit, ...] = ()):
        """``cam`` sees persons standing at these floor points at time ``t``."""
        boxes = []
        for x, y in floor_m:
            u = (x - OFFSETS[cam][0]) * SCALE
            v = (y - OFFSETS[cam][1]) * SCALE
            boxes.append((u - 30, v - 200, u + 30, v))
        self.seq += 1
        frame = FrameInfo(cam, self.seq, t, 1280, 1280)
        persons = Persons(np.array(boxes, np.float32).reshape(-1, 4),
                          np.full(len(boxes), 0.9, np.float32), frame)
        tracker = self.trackers[cam]

        def zones_of(feet_boxes: np.ndarray) -> ZoneReport:
            """P is the floor square 0.2 m around (3.0, 5.0): where a lost person's area is."""
            out = []
            for i, (x1, _, x2, y2) in enumerate(np.asarray(feet_boxes).reshape(-1, 4)):
                x = (x1 + x2) / 2 / SCALE + OFFSETS[cam][0]
                y = y2 / SCALE + OFFSETS[cam][1]
                if abs(x - 3.0) <= 0.2 and abs(y - 5.0) <= 0.2:
                    out.append(ZoneHit("P", "protective", i, 0.0))
            return ZoneReport(hits=tuple(out))

        update = tracker.update(persons, ZoneReport(hits=hits), t, (1280, 1280), zones_of)
        return self.persons.name(cam, tracker, update, t)


def test_one_person_seen_by_two_cameras_is_one_cell_person():
    cell = Cell()
    # cam1 first sees someone else (its track 1) far away: the person then is cam1's track 2
    cell.see("cam1", 0.0, (9.0, 9.0))
    named = []
    for i in range(6):
        t = 0.1 + 0.1 * i
        named.append((cell.see("cam0", t, (3.0, 5.0)), cell.see("cam1", t + 0.05, (3.0, 5.0),
                                                                  (9.0, 9.0))))
    cam1_tracks = cell.trackers["cam1"].tracks
    assert [t.track_id for t in cam1_tracks] == [1, 2]  # each camera numbers its own tracks
    for cam0, cam1 in named:
        assert cam0.person_ids == (2,)
        assert cam1.person_ids == (2, 1)  # the person is person 2 on both cameras
    assert all(not n.lines for pair in named for n in pair)  # not a guess: nothing to say


def test_two_persons_two_metres_apart_are_two_cell_persons():
    cell = Cell()
    a = cell.see("cam0", 0.0, (3.0, 5.0))
    b = cell.see("cam1", 0.05, (5.0, 5.0))
    assert a.person_ids == (1,) and b.person_ids == (2,)
    # both cameras then see both persons: each keeps its id on both
    a = cell.see("cam0", 0.1, (3.0, 5.0), (5.0, 5.0))
    b = cell.see("cam1", 0.15, (3.0, 5.0), (5.0, 5.0))
    assert a.person_ids == (1, 2)
    assert b.person_ids == (1, 2)


def test_a_link_stays_while_the_person_walks():
    cell = Cell()
    for i in range(30):  # 1.5 m/s along x for 3 s, both cameras at 5 fps in turn
        t = 0.2 * i
        x = 1.0 + 1.5 * t
        a = cell.see("cam0", t, (x, 5.0))
        # cam1 places the person further off with distance (up to 1 m > link_m): linked once,
        # the person stays person 1
        b = cell.see("cam1", t + 0.1, (x + 0.15 + 0.03 * i, 5.0))
        assert a.person_ids == (1,) and b.person_ids == (1,), (i, a, b)
        if i == 10:  # a second person steps in where the first one stood
            seen = cell.see("cam1", t + 0.15, (x + 0.15 + 0.03 * i, 5.0), (1.0, 5.0))
            assert seen.person_ids == (1, 2)


def test_a_walker_seen_by_the_second_camera_a_frame_later_at_one_fps_is_linked():
    """At 1-2 fps the other camera's placement is up to half a second old: moved by the
    person's floor velocity, it still meets the person."""
    cell = Cell()
    for i in range(3):  # cam0 alone at 1 fps: the person walks 1.4 m/s
        assert cell.see("cam0", float(i), (1.0 + 1.4 * i, 5.0)).person_ids == (1,)
    # cam1's first frame, 0.5 s after cam0's last: the person is 0.7 m further (> link_m)
    assert cell.see("cam1", 2.5, (3.8 + 0.7, 5.0)).person_ids == (1,)


def test_a_camera_without_calibration_names_its_tracks_with_the_camera():
    cell = Cell(calibrated=("cam0",))
    hit = ZoneHit("P", "protective", 0, 0.0)
    a = cell.see("cam0", 0.0, (3.0, 5.0), hits=(hit,))
    b = cell.see("cam1", 0.05, (3.0, 5.0), hits=(hit,))
    assert a.person_ids == (1,)
    assert b.person_ids == ("cam1:1",)  # never a bare 1: that is cam0's person
    assert [h.who for h in b.report.hits] == ["cam1:1"]
    merged = ZoneReport(hits=a.report.hits + b.report.hits)
    assert [r.message for r in frame_causes(merged).stops] == ["person 1 in P",
                                                               "person cam1:1 in P"]


def test_persons_seen_far_apart_in_time_are_not_linked():
    cell = Cell()
    assert cell.see("cam0", 0.0, (3.0, 5.0)).person_ids == (1,)
    cell.see("cam0", 0.1)  # cam0 loses the person (its track lives on, lost)
    assert cell.see("cam1", 2.0, (3.0, 5.0)).person_ids == (2,)


def test_a_guess_between_two_persons_takes_the_nearest_and_says_so_once():
    cell = Cell()
    assert cell.see("cam0", 0.0, (3.0, 5.0), (3.5, 5.0)).person_ids == (1, 2)
    first = cell.see("cam1", 0.05, (3.2, 5.0))  # 0.2 m from person 1, 0.3 m from person 2
    assert first.person_ids == (1,)
    (line,) = first.lines
    assert "seen again as person 1?" in line and "persons 1, 2 within 0.6 m" in line
    assert not cell.see("cam1", 0.15, (3.2, 5.0)).lines  # said once


def test_the_same_person_reported_by_two_cameras_is_one_cause():
    cell = Cell()
    a = cell.see("cam0", 0.0, (3.0, 5.0), hits=(ZoneHit("P", "protective", 0, 0.0),))
    b = cell.see("cam1", 0.05, (9.0, 9.0), (3.0, 5.0), hits=(ZoneHit("P", "protective", 1, 0.0),))
    assert b.person_ids == (2, 1)
    merged = ZoneReport(hits=a.report.hits + b.report.hits)
    assert [r.message for r in frame_causes(merged).stops] == ["person 1 in P"]


def test_link_settings_are_checked_with_the_config():
    with pytest.raises(ConfigError, match=r"\[tracking\] link_m: should be greater than 0"):
        parse_config({"tracking": {"link_m": 0.0}}, "monitor.toml")
    with pytest.raises(ConfigError, match=r"tracking\.link_s"):
        CellPersonsConfig(link_s=60.0)
    assert parse_config({"tracking": {"link_m": 0.4}}, "monitor.toml").tracking.link_m == 0.4


def test_two_persons_linked_by_mistake_never_clear_each_others_stop():
    """Red-team probe (passes on the first version: names only): persons X and Y stand
    0.4 m apart (closer than link_m), X inside protective zone P seen by cam0, Y beside it
    seen by cam1, and cam1's track of Y is linked to X's cell person. Whatever Y does --
    leave, stand in P too and then X leaves P, vanish -- the STOP stays while anyone is in P,
    and X lost inside P keeps holding it while Y, bearing X's id, is seen outside."""
    def causes(*named):
        reports = [n.report for n in named if n.report is not None]
        return [r.message for r in frame_causes(functools.reduce(
            merge_towards_danger, reports)).stops]

    cell = Cell()
    x_in = cell.see("cam0", 0.0, (3.0, 5.0), hits=(ZoneHit("P", "protective", 0, 0.0),))
    y_out = cell.see("cam1", 0.05, (3.4, 5.0))
    assert x_in.person_ids == y_out.person_ids == (1,)  # the mistake
    assert causes(x_in, y_out) == ["person 1 in P"]
    y_gone = cell.see("cam1", 0.15)  # Y leaves cam1's view: X is still in P
    assert causes(x_in, y_gone) == ["person 1 in P"]
    # both in P (one cause, two hits); then X walks out of P: Y's hit keeps the STOP
    x_in = cell.see("cam0", 0.2, (3.0, 5.0), hits=(ZoneHit("P", "protective", 0, 0.0),))
    y_in = cell.see("cam1", 0.25, (3.4, 5.0), hits=(ZoneHit("P", "protective", 0, 0.0),))
    assert causes(x_in, y_in) == ["person 1 in P"]
    x_out = cell.see("cam0", 0.3, (3.0, 5.0))  # its zone check: outside P now
    assert causes(x_out, y_in) == ["person 1 in P"]
    # X back in P, then lost there (hidden); Y, named person 1 too, seen outside P by cam1
    cell.see("cam0", 0.4, (3.0, 5.0), hits=(ZoneHit("P", "protective", 0, 0.0),))
    cell.see("cam0", 0.5, (3.0, 5.0), hits=(ZoneHit("P", "protective", 0, 0.0),))
    x_lost = cell.see("cam0", 0.6)
    y_out = cell.see("cam1", 0.65, (3.4, 5.0))
    assert causes(x_lost, y_out) == ["person 1 lost inside P"]
    assert [h.who for h in x_lost.report.hits] == [1] and x_lost.report.hits[0].lost
