"""An operator's acceptance of an object since commissioning (monitor/wire/object_accepts.py,
monitor/health/acceptance.py): the bus-side checks refuse unsigned, wrongly signed, replayed
and foreign requests in one line; the pipeline's judgement refuses bad input in one line and
accepts the objects standing in the named zone; the status says the cell changed."""

from __future__ import annotations

import json

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from monitor.cli.status_text import status_text
from monitor.config import CameraConfig
from monitor.health.acceptance import (
    OBJECT_ACCEPT_REFUSED,
    OBJECT_ACCEPTED,
    changed_cell,
    changed_signature,
    judge_accept,
)
from monitor.health.objects import OBJECT_IN_ZONE, objects_of
from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig
from monitor.replay import scenarios as sc
from monitor.service.setup import no_reference_note
from monitor.wire.object_accepts import (
    ACCEPT_SCHEMA,
    AcceptGate,
    AcceptRefused,
    ObjectAccept,
    accept_payload,
)
from monitor.wire.signing import Signer
from monitor.zones import parse_cell

KEY = "workcell/cell1/safety/objects/accept"
ANNA, CARL = Signer(Ed25519PrivateKey.generate()), Signer(Ed25519PrivateKey.generate())
NOW = 1_800_000_000.0


def _gate(operators=None) -> AcceptGate:
    return AcceptGate({"anna": ANNA.key.public_key()} if operators is None else operators,
                      "cell1", KEY)


def _payload(**over) -> bytes:
    args = {"operator": "anna", "camera": "cam0", "zone": "robot-protective",
            "cell": "cell1", "boot": "b1", "wall": NOW, **over}
    return accept_payload(args.pop("operator"), args.pop("camera"), args.pop("zone"), **args)


def _refusal(gate: AcceptGate, payload: bytes, signature: bytes | None) -> str:
    with pytest.raises(AcceptRefused) as info:
        gate.check(payload, signature, 5.0, NOW, boot="b1")
    text = str(info.value)
    assert "\n" not in text and text  # one line
    return text


def test_the_gate_takes_a_signed_request_and_refuses_the_rest_in_one_line():
    gate = _gate()
    payload = _payload(request_id="r1")
    req = gate.check(payload, ANNA.sign(KEY, payload), 5.0, NOW, boot="b1")
    assert (req.operator, req.camera, req.zone, req.time) == ("anna", "cam0",
                                                             "robot-protective", 5.0)
    assert "already used (replayed)" in _refusal(gate, payload, ANNA.sign(KEY, payload))
    other = _payload(request_id="r2")
    assert "unsigned" in _refusal(gate, other, None)
    assert "signature does not match operator 'anna'" in _refusal(gate, other,
                                                                  CARL.sign(KEY, other))
    # signed for another key (a mute's signature is no acceptance)
    assert "signature does not match" in _refusal(gate, other, ANNA.sign(KEY + "x", other))
    carl = _payload(operator="carl", request_id="r3")
    assert "unknown operator 'carl'" in _refusal(gate, carl, CARL.sign(KEY, carl))
    for over, words in (({"cell": "cell2"}, "for cell 'cell2'"),
                        ({"boot": "b0"}, "before a restart"),
                        ({"wall": NOW - 120}, "off the monitor's clock")):
        p = _payload(request_id=f"x{len(words)}", **over)
        assert words in _refusal(gate, p, ANNA.sign(KEY, p)), over
    assert "without a valid zone" in _refusal(gate, _payload(zone=""), None)
    junk = json.dumps({"schema": ACCEPT_SCHEMA, "operator": 3}).encode()
    assert "without a valid operator" in _refusal(gate, junk, None)
    assert "is not a" in _refusal(gate, b"[1]", None)
    # no operators file: every acceptance refused (never unsigned, unlike lab resets)
    assert "are refused" in _refusal(AcceptGate(None, "cell1", KEY), other,
                                     ANNA.sign(KEY, other))


@pytest.fixture(scope="module")
def crate():
    """The crate scene's object check after the crate has stood for longer than persist_s."""
    scenario = sc.select(["crate-after-reference"], 5.0)[0]
    cell = parse_cell(scenario.zone_data())
    watches = objects_of(cell, {"cam0": scenario.scene.reference()})
    image, _ = next(iter(scenario.scene.frames()))
    return cell, watches, image


def _watches(crate):
    cell, _, image = crate
    scenario = sc.select(["crate-after-reference"], 5.0)[0]
    watches = objects_of(cell, {"cam0": scenario.scene.reference()})
    for t in (0.0, 1.0, 2.0, 3.2):
        watches["cam0"].check(image, [], t)
    return watches


def _req(camera="cam0", zone="robot-protective", rid="r1") -> ObjectAccept:
    return ObjectAccept("anna", camera, zone, rid, 10.0, NOW, "crate of parts")


def test_bad_input_is_one_line_naming_the_problem(crate):
    watches = _watches(crate)
    cams, zones = ("cam0", "cam1"), ("robot-protective", "robot-warning", "far-warning")
    for req, words in ((_req(camera="cam9"), "unknown camera 'cam9'"),
                       (_req(zone="nowhere"), "unknown zone 'nowhere'"),
                       (_req(camera="cam1"), "cam1 has no commissioning reference"),
                       (_req(zone="far-warning"), "no object stands in zone far-warning")):
        outcome, alert = judge_accept(watches, cams, zones, req, 10.0)
        assert not outcome.accepted and words in outcome.reason, outcome.reason
        assert "\n" not in outcome.reason
        assert alert.kind == OBJECT_ACCEPT_REFUSED and alert.details["operator"] == "anna"
    # nothing was accepted by the refusals: the fault holds
    assert [f.name for f in watches["cam0"].faults()] == [OBJECT_IN_ZONE]


def test_accepted_the_object_no_longer_holds_the_cell_and_the_status_says_so(crate):
    watches = _watches(crate)
    (fault,) = watches["cam0"].faults()
    assert "monitor objects accept --camera cam0 --zone robot-protective" in fault.reason
    before = changed_signature(watches)
    # (the walker standing at the warning zone's edge in this frame, given no person box here,
    # is a second, warning-zone object: its image covers that zone's floor)
    (unaccepted,) = [c for c in changed_cell(watches) if c["protective"]]
    assert unaccepted["accepted_by"] is None and unaccepted["protective"]
    text = status_text({"changed_since_commissioning": [unaccepted]})
    assert "cell changed since commissioning: object at x 0.5 m, y -0.8 m in " \
           "robot-protective, robot-warning on cam0 (NOT accepted: STOP, resets refused " \
           "until `monitor objects accept --camera cam0 --zone robot-protective`)" in text
    outcome, alert = judge_accept(watches, ("cam0",), ("robot-protective",), _req(), 10.0)
    assert outcome.accepted, outcome.reason
    assert alert.kind == OBJECT_ACCEPTED and alert.details["note"] == "crate of parts"
    assert alert.details["request_id"] == "r1" and alert.details["wall"] == NOW
    assert watches["cam0"].faults() == []  # no longer holds the cell by itself
    assert changed_signature(watches) != before  # the status is published anew
    (accepted,) = [c for c in changed_cell(watches) if c["protective"]]
    assert accepted["accepted_by"] == "anna" and accepted["accepted_wall"] == NOW
    text = status_text({"changed_since_commissioning": [accepted]})
    assert "object at x 0.5 m, y -0.8 m in robot-protective, robot-warning on cam0 " \
           "(accepted by anna at 20" in text
    # its shadow stays unseen: a foot position behind it is hidden
    x1, _, x2, y2 = accepted["box_px"]
    assert watches["cam0"].hidden_cells([[(x1 + x2) / 2, y2 - 2]])[0]
    again, _ = judge_accept(watches, ("cam0",), ("robot-protective",), _req(rid="r2"), 11.0)
    assert not again.accepted and "already accepted (by anna)" in again.reason


def test_the_status_says_nothing_changed_when_no_object_stands():
    assert "cell changed" not in status_text({})
    assert "cell changed" not in status_text({"changed_since_commissioning": "junk"})
    # a hostile entry reads as not accepted, never as accepted
    text = status_text({"changed_since_commissioning": [{"floor_m": ["a", 1],
                                                         "protective": True}]})
    assert "NOT accepted" in text and "image box ?" in text


def test_without_a_reference_start_and_status_say_objects_are_not_noticed(detector):
    scenario = sc.select(["crate-after-reference"], 5.0)[0]
    cell = parse_cell(scenario.zone_data())
    cameras = [CameraConfig(id="cam0")]
    blind = Pipeline(detector, "cam0", PolicyConfig(), cell)
    note = no_reference_note(blind, cameras)
    assert note is not None and note.startswith("camera cam0: no commissioning reference")
    assert "objects put into the protective and warning zones since commissioning are not " \
           "noticed" in note
    # the status carries it (run.py: changes_unwatched) and `monitor status` shows it
    assert f"WARNING: {note}" in status_text({"changes_unwatched": note})
    watched = Pipeline(detector, "cam0", PolicyConfig(), cell,
                       references={"cam0": scenario.scene.reference()})
    assert no_reference_note(watched, cameras) is None
