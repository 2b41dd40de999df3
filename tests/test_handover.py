"""Hand-over of holds between the monitors of one cell, the pure part (monitor/handover.py) and
the gate of the bus edge (monitor/bus_holds.py): which of my zones a departure reaches, one
hold per entry, release rules, and refused messages (unsigned, forged, unknown role, stale,
replayed)."""

from __future__ import annotations

import json

import numpy as np
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from monitor import zones as zn
from monitor.bus_holds import HoldsGate, holds_payload
from monitor.busconfig import BusKeys
from monitor.handover import Entry, HandedHolds, entries_of, reached_zones, zone_footprints
from monitor.policy.causes import frame_causes
from monitor.scene import Camera
from monitor.scene.cell import camera_calibration
from monitor.signing import Signer
from monitor.tracks import PersonTracker
from monitor.types import Persons

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
    assert desk.release_seen([(8.0, 0.0)]) == ()  # someone far away: the hold stays
    assert desk.report() is not None
    assert len(desk.release_seen([(4.8, 0.3)])) == 1  # seen near where they left
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
    role, boot, entries = g.check(*message(), now=0.0, wall_now=1000.5)
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
