"""The monitor host's wall clock steps (NTP) back or forward by an hour while it runs.

Safety timing is monotonic; the wall clock only judges signed requests (the clock window and
replay memory) and stamps. These tests feed the gates jumped ``wall_now`` values: a step must
never turn a captured request into one the gate accepts again."""

from __future__ import annotations

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from monitor.cases.mute_requests import MuteGate, MuteRefused, mute_payload
from monitor.cases.zone_apply import ApplyGate, ApplyRefused, apply_payload
from monitor.wire.resets import ResetGate, ResetPolicy, ResetRefused, reset_payload
from monitor.wire.signing import Signer

T = 1_732_400_000.0
HOUR = 3600.0
BOOT = "b" * 16
HASH = "9c1f" * 16


@pytest.fixture
def anna():
    key = Ed25519PrivateKey.generate()
    return {"anna": key.public_key()}, Signer(key)


def _mute(signer, rid, wall):
    return mute_payload("anna", "robot-protective", 30.0, cell="cell1", boot=BOOT,
                        request_id=rid, wall=wall)


def _apply(signer, rid, wall):
    return apply_payload("anna", HASH, cell="cell1", boot=BOOT, request_id=rid, wall=wall)


@pytest.mark.parametrize("kind", ["mute", "apply"])
def test_a_request_captured_before_the_clock_stepped_back_is_not_accepted_again(anna, kind):
    operators, signer = anna
    key = f"workcell/cell1/safety/{kind}"
    if kind == "mute":
        gate, make, refused = MuteGate(operators, "cell1", key), _mute, MuteRefused
    else:
        gate, make, refused = ApplyGate(operators, "cell1", key), _apply, ApplyRefused
    # the host ran an hour fast (operator's host too, same NTP): a request at "T + 1 h"
    captured = make(signer, "anna-1", T + HOUR)
    gate.check(captured, signer.sign(key, captured), 0.0, T + HOUR, boot=BOOT)
    later = make(signer, "anna-2", T + HOUR + 120.0)  # a later one: the first id is forgotten
    gate.check(later, signer.sign(key, later), 120.0, T + HOUR + 120.0, boot=BOOT)
    # NTP steps the clock back an hour; an hour later the captured request's time comes round
    with pytest.raises(refused, match="stepped back"):
        gate.check(captured, signer.sign(key, captured), HOUR + 1.0, T + HOUR + 1.0, boot=BOOT)
    # a fresh request after the clock has passed the forgotten one is accepted again
    fresh = make(signer, "anna-3", T + HOUR + 200.0)
    gate.check(fresh, signer.sign(key, fresh), HOUR + 200.0, T + HOUR + 200.0, boot=BOOT)


@pytest.mark.parametrize("step", [-HOUR, HOUR])
def test_a_request_across_a_clock_step_is_refused_not_misread(anna, step):
    """The monitor's clock stepped, the operator's did not: refused with the clock's reason."""
    operators, signer = anna
    key = "workcell/cell1/safety/reset"
    gate = ResetGate(ResetPolicy(operators, "cell1", key))
    body = reset_payload("anna", "anna-r1", cell="cell1", wall=T, boot=BOOT, latch="1-ab")
    with pytest.raises(ResetRefused, match="off the monitor's clock"):
        gate.check(body, signer.sign(key, body), 0.0, T + step, boot=BOOT, latch="1-ab")
    # back in step: the same (never accepted) request passes the bus gate once, then never
    assert gate.check(body, signer.sign(key, body), 1.0, T + 1.0, boot=BOOT,
                      latch="1-ab").latch == "1-ab"
    with pytest.raises(ResetRefused, match="replayed"):
        gate.check(body, signer.sign(key, body), 2.0, T + 2.0, boot=BOOT, latch="1-ab")
