"""Hand-over of holds between the monitors of one cell, the pure part (monitor/tracking/handover.py)
and the gate of the bus edge (monitor/bus/holds.py): which of my zones a departure reaches, one hold
per entry, release rules, and refused messages (unsigned, forged, unknown role, stale, replayed)."""

from __future__ import annotations

import json

import numpy as np
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from monitor import zones as zn
from monitor.bus.holds import HoldsGate, holds_payload
from monitor.policy.causes import frame_causes
from monitor.scene import Camera
from monitor.scene.cell import camera_calibration
from monitor.tracking.handover import (
    MAX_ENTRIES,
    Entry,
    HandedHolds,
    entries_of,
    reached_zones,
    silent_peers,
    zone_footprints,
)
from monitor.tracking.tracks import PersonTracker, Track
from monitor.types import Persons, ZoneHit, ZoneReport
from monitor.wire.busconfig import BusKeys
from monitor.wire.signing import Signer

PREFIX = "workcell/th/"
CAM_B = Camera.look_at("camB", (640, 360), np.array([[450.0, 0, 320], [0, 450.0, 180],
                                                      [0, 0, 1]]),
                       position_m=(6.0, -6.0, 3.2), target_m=(6.0, 0.0, 0.8))


def cell_b(near: tuple[float, float] = (4.5, 6.0), far: tuple[float, float] = (9.0, 10.5)
           ) -> zn.Cell:
    """Monitor-b's cell: a protective box at x in ``near`` and one at x in ``far``."""
    def box(zid, xs):
        return {"id": zid, "kind": "protective", "shape": "box", "min_m": [xs[0], -1.0, 0.0],
                "max_m": [xs[1], 1.0, 2.2], "unobserved_ok": True}
    return zn.parse_cell({
        "version": 1, "name": "b",
        "cameras": [{"id": "camB", "width": 640, "height": 360,
                     "calibration": camera_calibration(CAM_B)}],
        "zones": [box("b-near", near), box("b-far", far),
                  {"id": "b-slow", "kind": "warning", "speed_scale": 0.3, "shape": "box",
                   "min_m": [3.0, -2.0, 0.0], "max_m": [4.0, 2.0, 2.2]}]})


def departure(person: int = 3, x: float = 4.0, wall: float = 1000.0, zones=()) -> Entry:
    return Entry(person, "departure", (x, 0.0), wall, tuple(zones), "camA")


def test_a_departure_half_a_metre_from_my_zone_is_held_five_metres_away_is_not():
    feet = zone_footprints(cell_b())
    assert set(feet) == {"b-near", "b-far"}  # protective zones only
    assert reached_zones(departure(x=4.0), feet, 1.5) == ("b-near",)  # 0.5 m from it
    assert reached_zones(departure(x=4.0), feet, 0.4) == ()  # beyond a shorter reach
    assert reached_zones(Entry(3, "departure", (4.0, 6.0), 0.0), feet, 1.5) == ()  # 5 m
    assert reached_zones(departure(x=5.0), feet, 0.0) == ("b-near",)  # inside it
    # a zone with the id the entry held: held wherever the point is
    assert reached_zones(departure(x=-20.0, zones=("b-far", "a-only")), feet, 1.5) == (
        "b-far",)


def test_a_taken_entry_is_my_person_lost_stop_with_readable_words():
    desk = HandedHolds(walk_speed_mps=1.5, reach_s=1.0)
    new = desk.take("monitor-a", "boot1", [departure(wall=998.0), departure(7, x=-3.0)],
                    cell_b(), now=50.0, wall_now=1000.0)
    assert [h.zones for h in new] == [("b-near",)]  # person 7 reaches none of my zones
    assert new[0].since == 48.0  # seen 2 s ago, in my clock
    causes = frame_causes(desk.report())
    assert [r.code for r in causes.stops] == ["person_lost"]
    assert causes.stops[0].zone_id == "b-near"
    assert causes.stops[0].message == ("person 3 of monitor-a left its view toward b-near "
                                       "(handed over)")


def test_the_same_entry_twice_is_one_hold_and_a_new_boot_is_a_new_person():
    desk = HandedHolds()
    for _ in range(3):  # the peer repeats its list at every heartbeat
        desk.take("monitor-a", "boot1", [departure()], cell_b(), 1.0, 1000.0)
    assert len(desk.holds) == 1
    assert len(desk.report().hits) == 1
    desk.take("monitor-a", "boot2", [departure()], cell_b(), 1.0, 1000.0)  # restarted peer
    assert len(desk.holds) == 2


def test_a_hold_ends_when_a_person_is_seen_near_the_point_or_on_confirm_clear():
    desk = HandedHolds(walk_speed_mps=1.5, reach_s=1.0)
    desk.take("monitor-a", "b", [departure(x=4.0)], cell_b(), 1.0, 1000.0)
    assert desk.release_seen([((8.0, 0.0), ("b-near",))]) == ()  # far away: the hold stays
    assert desk.report() is not None
    # seen near where they left, inside the zone (their own hits hold it from now on)
    assert len(desk.release_seen([((4.8, 0.3), ("b-near",))])) == 1
    assert desk.report() is None
    # once ended, the peer's repeats of the same entry take nothing again
    desk.take("monitor-a", "b", [departure(x=4.0)], cell_b(), 2.0, 1000.0)
    assert desk.report() is None
    desk.take("monitor-a", "b", [departure(4, x=4.0)], cell_b(), 2.0, 1000.0)
    assert [h.entry.person for h in desk.drop()] == [4]
    assert desk.report() is None


def to_floor(px: np.ndarray):
    """100 px = 1 m: a hand-made calibration for the tracker."""
    px = np.asarray(px, float)
    return np.stack([px[:, 0] / 100.0, (720.0 - px[:, 1]) / 100.0], axis=1), \
        np.ones(len(px), bool)


def test_a_person_leaving_the_view_is_handed_over_for_keep_s():
    tracker = PersonTracker(to_floor=to_floor)
    t = 0.0
    for i, cx in enumerate([1100, 1150, 1200, 1245, None]):  # out at the right edge
        t = i / 10
        boxes = np.array([[cx - 40, 360, cx + 40, 600]] if cx else [], np.float32
                         ).reshape(-1, 4)
        tracker.update(Persons(boxes, np.full(len(boxes), 0.9, np.float32)), None, t,
                       (1280, 720))
    (entry,) = entries_of({"camA": tracker.tracks}, t, 1000.0, keep_s=5.0)
    assert entry.kind == "departure" and entry.zones == ()
    assert np.allclose(entry.floor_m, (12.45, 1.2))
    assert entry.wall == 1000.0 - 0.1
    assert entries_of({"camA": tracker.tracks}, t + 5.2, 1005.2, keep_s=5.0) == ()
    # without a calibration there is no floor point: nothing can be handed over
    blind = PersonTracker()
    for i, cx in enumerate([1150, 1200, 1245, None]):
        boxes = np.array([[cx - 40, 360, cx + 40, 600]] if cx else [], np.float32
                         ).reshape(-1, 4)
        blind.update(Persons(boxes, np.full(len(boxes), 0.9, np.float32)), None, i / 10,
                     (1280, 720))
    assert blind.tracks[0].left_view
    assert entries_of({"camA": blind.tracks}, 0.3, 1000.0, keep_s=5.0) == ()


# --- the gate: only a peer's own signed, fresh, new messages ---------------------------------

KEY_A = Ed25519PrivateKey.generate()
KEY_C = Ed25519PrivateKey.generate()


def gate() -> HoldsGate:
    return HoldsGate("th", PREFIX, "monitor-b", {"monitor-a": KEY_A.public_key()})


def message(role: str = "monitor-a", seq: int = 1, wall: float = 1000.0, cell: str = "th",
            key=KEY_A, boot: str = "boot1") -> tuple[str, bytes, bytes]:
    key_expr = BusKeys.of(PREFIX, role).holds
    payload = holds_payload(cell, role, boot, seq, wall, (departure(wall=wall),))
    return key_expr, payload, Signer(key).sign(key_expr, payload)


def test_the_gate_takes_a_peers_signed_message():
    g = gate()
    role, boot, entries, _ = g.check(*message(), now=0.0, wall_now=1000.5)
    assert (role, boot, entries) == ("monitor-a", "boot1", (departure(wall=1000.0),))
    assert g.counts() == {}


def test_the_gate_refuses_forged_unknown_stale_and_replayed_messages():
    g = gate()
    key_expr, payload, signature = message()
    refused = [
        (key_expr, payload, None),  # unsigned
        (key_expr, payload, b"x" * 64),  # wrongly signed
        message(key=KEY_C),  # signed with another key
        message(role="monitor-c", key=KEY_C),  # a role not expected
        # signed for monitor-c's key, sent on monitor-a's: the signature covers the key
        (message(role="monitor-a")[0], *message(role="monitor-c", key=KEY_A)[1:]),
        message(cell="other"),  # another cell's
        message(wall=900.0),  # outside the clock window
    ]
    for msg in refused:
        assert g.check(*msg, now=0.0, wall_now=1000.0) is None
    assert g.check(key_expr, payload, signature, now=0.0, wall_now=1000.0) is not None
    assert g.check(key_expr, payload, signature, now=0.0, wall_now=1000.0) is None  # replay
    assert g.check(*message(seq=2), now=0.0, wall_now=1000.0) is not None
    assert g.counts() == {"unsigned": 1, "signature": 3, "unknown_role": 1, "invalid": 1,
                          "stale": 1, "replayed": 1}
    alert = g.alert(0.0)
    assert alert is not None and alert.kind == "foreign_holds" and "8 holds" in alert.message
    assert g.alert(1.0) is None  # once per burst
    # a signed message with a malformed entry is refused whole
    body = json.loads(payload)
    body["seq"], body["entries"] = 3, [{"person": 1, "kind": "departure", "floor_m": [1.0]}]
    bad = json.dumps(body).encode()
    assert g.check(key_expr, bad, Signer(KEY_A).sign(key_expr, bad), 0.0, 1000.0) is None


# --- attacks on the hand-over (each failed on the first version) ----------------------------

def walk_and_vanish(xs, frame=(1280, 720)) -> PersonTracker:
    """A person walking at these box centres (px) on the to_floor calibration, then gone."""
    tracker = PersonTracker(to_floor=to_floor)
    for i, cx in enumerate([*xs, None]):
        boxes = np.array([[cx - 40, 300, cx + 40, 540]] if cx else [], np.float32
                         ).reshape(-1, 4)
        tracker.update(Persons(boxes, np.full(len(boxes), 0.9, np.float32)), None, i / 10,
                       frame)
    return tracker


def test_a_person_lost_behind_a_fixture_outside_my_zones_is_handed_over():
    """Lost mid-view (not at an image edge), outside every zone of monitor-a: monitor-b's
    zone 0.3 m away may be where they are, unseen by camera B."""
    tracker = walk_and_vanish([300, 330, 360, 390])  # floor x 3.0 .. 3.9 m, y 1.8 m
    (track,) = tracker.tracks
    assert track.lost and not track.held and not track.left_view
    t = 0.4
    (entry,) = entries_of({"camA": tracker.tracks}, t, 1000.0, keep_s=5.0)
    assert entry.kind == "lost" and np.allclose(entry.floor_m, (3.9, 1.8))
    assert entries_of({"camA": tracker.tracks}, t + 5.2, 1005.2, keep_s=5.0) == ()
    desk = HandedHolds(walk_speed_mps=1.5, reach_s=1.0)
    (hold,) = desk.take("monitor-a", "boot1", [entry], cell_b(), 50.0, 1000.0)
    assert hold.zones == ("b-near",)
    assert "person 1 of monitor-a was lost near b-near" in desk.report().hits[0].note
    # the wire: a receiver takes the new kind
    g = gate()
    key_expr = BusKeys.of(PREFIX, "monitor-a").holds
    payload = holds_payload("th", "monitor-a", "boot1", 1, 1000.0, (entry,))
    _, _, got, _ = g.check(key_expr, payload, Signer(KEY_A).sign(key_expr, payload), 0.0, 1000.0)
    assert got == (entry,)


def seen_by_b(floor_m: tuple[float, float], zones: tuple[str, ...]) -> PersonTracker:
    """Camera B's tracker seeing one person standing at ``floor_m``, in ``zones``."""
    tracker = PersonTracker(to_floor=to_floor)
    x, y = floor_m
    box = np.array([[x * 100 - 30, 720 - y * 100 - 200, x * 100 + 30, 720 - y * 100]],
                   np.float32)
    hits = tuple(ZoneHit(z, "protective", 0, 0.0) for z in zones)
    tracker.update(Persons(box, np.full(1, 0.9, np.float32)), ZoneReport(hits=hits), 0.0,
                   (1280, 720))
    return tracker


def test_a_second_person_beside_my_zone_does_not_release_the_hidden_ones_hold():
    """Person 3 left A's view at x = 4.0 toward b-near (4.5 .. 6.0) and is hidden from camera
    B inside it; a second person B sees at x = 4.2, within reach of the point but outside
    b-near, must not end the hold (the first version did: a miss)."""
    desk = HandedHolds(walk_speed_mps=1.5, reach_s=1.0)
    desk.take("monitor-a", "b", [departure(x=4.0)], cell_b(), 1.0, 1000.0)
    assert desk.decide([seen_by_b((4.2, 0.0), ())]) is not None
    assert [h.zones for h in desk.holds] == [("b-near",)]
    # a person seen inside b-near near the point: their own hits hold it from now on
    assert desk.decide([seen_by_b((4.8, 0.0), ("b-near",))]) is None
    # a hold on two zones (one by the id the peer held): one seen inside b-near ends b-near
    # only; b-far stays held until someone is seen there or a confirm-clear
    desk.take("monitor-a", "b", [departure(5, x=4.0, zones=("b-far",))], cell_b(), 1.0,
              1000.0)
    report = desk.decide([seen_by_b((4.8, 0.0), ("b-near",))])
    assert [h.zone_id for h in report.hits] == ["b-far"]
    assert [r.code for r in frame_causes(report).stops] == ["person_lost"]


def test_a_peer_with_more_persons_than_a_message_carries_holds_every_protective_zone():
    entries = tuple(departure(i, x=-20.0 - i) for i in range(MAX_ENTRIES + 6))  # all far off
    key_expr = BusKeys.of(PREFIX, "monitor-a").holds
    payload = holds_payload("th", "monitor-a", "boot1", 1, 1000.0, entries)
    assert json.loads(payload)["overflow"] == 6
    for body in (payload, json.dumps({**json.loads(payload), "overflow": 0, "entries": [
            e.to_dict() for e in entries]}).encode()):  # a sender that lists them all
        g, desk = gate(), HandedHolds()
        _, _, got, _ = g.check(key_expr, body, Signer(KEY_A).sign(key_expr, body), 0.0, 1000.0)
        assert len(got) == MAX_ENTRIES + 1 and got[-1].kind == "overflow"
        desk.take("monitor-a", "boot1", got, cell_b(), 1.0, 1000.0)
        assert [h.zones for h in desk.holds] == [("b-far", "b-near")]
        assert "more persons than a message carries" in desk.report().hits[0].note
        # repeated every heartbeat: one hold; after a confirm-clear it is taken again
        desk.take("monitor-a", "boot1", got, cell_b(), 1.1, 1000.1)
        assert len(desk.holds) == 1
        desk.drop()
        desk.take("monitor-a", "boot1", got, cell_b(), 1.2, 1000.2)
        assert len(desk.holds) == 1
    # a negative or non-integer overflow is malformed
    bad = json.dumps({**json.loads(payload), "overflow": -1}).encode()
    assert gate().check(key_expr, bad, Signer(KEY_A).sign(key_expr, bad), 0.0, 1000.0) is None


def test_a_person_with_no_finite_floor_point_does_not_silence_the_others():
    """A NaN floor point of one track made the whole signed message unreadable to the peer
    (every entry lost); it is left out, the others go."""
    good = Track(1, (0, 0, 10, 10), 0.0, (0.0, 0.0), (4.0, 0.0), lost=True)
    bad = Track(2, (0, 0, 10, 10), 0.0, (0.0, 0.0), (float("nan"), 0.0), lost=True)
    entries = entries_of({"camA": (good, bad)}, 0.1, 1000.0, keep_s=5.0)
    assert [e.person for e in entries] == [1]
    key_expr = BusKeys.of(PREFIX, "monitor-a").holds
    payload = holds_payload("th", "monitor-a", "boot1", 1, 1000.0, entries)
    got = gate().check(key_expr, payload, Signer(KEY_A).sign(key_expr, payload), 0.0, 1000.0)
    assert got is not None and [e.person for e in got[2]] == [1]


def test_a_person_lost_again_later_is_handed_over_again():
    """The same person id, a second loss (``seen`` later): a new entry, not a repeat."""
    desk = HandedHolds()
    first = Entry(3, "lost", (-20.0, 0.0), 990.0, (), "camA", seen=1.0)  # reaches nothing
    desk.take("monitor-a", "boot1", [first], cell_b(), 1.0, 1000.0)
    assert desk.holds == ()
    again = Entry(3, "departure", (4.0, 0.0), 999.0, (), "camA", seen=10.0)
    desk.take("monitor-a", "boot1", [again], cell_b(), 2.0, 1000.0)
    assert [h.zones for h in desk.holds] == [("b-near",)]


def test_a_zone_without_a_floor_footprint_is_held_by_its_id():
    """A protective polygon of an uncalibrated camera of monitor-b has no footprint; a peer
    entry that held a zone of that id must still hold it."""
    data = {"version": 1, "name": "b",
            "cameras": [{"id": "camB", "width": 640, "height": 360,
                         "calibration": camera_calibration(CAM_B)},
                        {"id": "camC", "width": 640, "height": 360}],
            "zones": [{"id": "shared", "kind": "protective", "shape": "polygon",
                       "camera": "camC", "points_px": [[10, 10], [300, 10], [300, 300]]}]}
    cell = zn.parse_cell(data)
    assert zone_footprints(cell) == {}
    desk = HandedHolds()
    (hold,) = desk.take("monitor-a", "b", [departure(x=-20.0, zones=("shared",))], cell, 1.0,
                        1000.0)
    assert hold.zones == ("shared",)


def test_a_peer_silent_or_refused_for_longer_than_the_timeout_is_a_stop():
    """A peer whose clock is off by more than the window (every message 'stale'), or whose
    messages are all refused or never sent, hands over nothing: that is a STOP, not a RUN."""
    assert silent_peers({"monitor-a": 10.0}, 0.0, 10.5, 1.0, 5.0) == ()
    (f,) = silent_peers({"monitor-a": 10.0}, 0.0, 11.5, 1.0, 5.0, "stale 12")
    assert f.name == "handover_silent" and f.stop and not f.latch
    assert "monitor-a" in f.reason and "stale 12" in f.reason
    # silent past keep_s after being heard: its entries of that time are gone -> latched
    (f,) = silent_peers({"monitor-a": 10.0}, 0.0, 16.0, 1.0, 5.0)
    assert f.latch
    # never heard since start (a cell starting up): a STOP, never latched
    (f,) = silent_peers({"monitor-a": None}, 0.0, 30.0, 1.0, 5.0)
    assert f.stop and not f.latch
    (f,) = silent_peers({"monitor-a": float("nan")}, 0.0, 30.0, 1.0, 5.0)  # NaN: silent
    assert f.stop


def test_probes_that_hold_on_the_first_version():
    """Probed, no hole found (these pass on the first version too): a replay of an older
    boot's message is stale; a message on my own role's key or naming my role is refused;
    a zone id the receiver has as a warning zone is not held (only protective zones are);
    a non-finite floor point from the wire is refused."""
    g = gate()
    assert g.check(*message(boot="boot0", wall=990.0), now=0.0, wall_now=1000.0) is None
    assert g.check(*message(role="monitor-b", key=KEY_A), now=0.0, wall_now=1000.0) is None
    key_expr = BusKeys.of(PREFIX, "monitor-a").holds
    body = json.loads(message()[1])
    body["role"] = "monitor-b"
    forged = json.dumps(body).encode()
    assert g.check(key_expr, forged, Signer(KEY_A).sign(key_expr, forged), 0.0, 1000.0) is None
    assert g.counts() == {"stale": 1, "unknown_role": 1, "invalid": 1}
    desk = HandedHolds()
    desk.take("monitor-a", "b", [departure(x=-20.0, zones=("b-slow",))], cell_b(), 1.0,
              1000.0)
    assert desk.holds == ()
    try:
        Entry.from_dict({"person": 1, "kind": "lost", "floor_m": [float("inf"), 0.0],
                         "wall": 1.0})
    except ValueError:
        pass
    else:
        raise AssertionError("an infinite floor point was taken")
