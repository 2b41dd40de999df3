"""The checks every signed request shares (monitor.wire.signed_requests): signer, cell, clock
window, request ids, and the one order a SignedGate runs them in. Each gate's own tests (resets,
mutes, zone applies, selections) check the wording their users see; these check the rules
themselves, once."""

from __future__ import annotations

import math

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from monitor.cases.mute_requests import MuteGate, MuteRefused, mute_payload
from monitor.cases.zone_apply import ApplyGate, ApplyRefused, apply_payload
from monitor.wire.object_accepts import AcceptGate, AcceptRefused, accept_payload
from monitor.wire.signed_requests import (
    MAX_REMEMBERED,
    RequestIds,
    RequestKind,
    check_cell,
    check_signer,
    check_window,
)
from monitor.wire.signing import Signer


class Refused(ValueError):
    pass


KIND = RequestKind("thing", "things", Refused)
KEY = "safety/thing"


def _signer() -> tuple[Signer, dict]:
    private = Ed25519PrivateKey.generate()
    return Signer(private), {"anna": private.public_key()}


def test_only_a_listed_signer_with_its_own_signature_passes() -> None:
    signer, signers = _signer()
    payload = b'{"x": 1}'
    check_signer(KIND, signers, "anna", KEY, payload, signer.sign(KEY, payload))
    with pytest.raises(Refused, match="unknown operator 'bob'"):
        check_signer(KIND, signers, "bob", KEY, payload, signer.sign(KEY, payload))
    with pytest.raises(Refused, match="unsigned thing in the name of 'anna'"):
        check_signer(KIND, signers, "anna", KEY, payload, None)
    with pytest.raises(Refused, match="signature does not match"):  # another payload
        check_signer(KIND, signers, "anna", KEY, b'{"x": 2}', signer.sign(KEY, payload))
    with pytest.raises(Refused, match="signature does not match"):  # another key
        check_signer(KIND, signers, "anna", "safety/other", payload, signer.sign(KEY, payload))
    other, _ = _signer()
    with pytest.raises(Refused, match="signature does not match"):  # someone else's key
        check_signer(KIND, signers, "anna", KEY, payload, other.sign(KEY, payload))


def test_no_signers_file_refuses_everything_unless_unsigned_is_allowed() -> None:
    with pytest.raises(Refused, match=r"no operators configured .*things are refused"):
        check_signer(KIND, None, "anna", KEY, b"{}", b"x" * 64)
    check_signer(KIND, None, "anna", KEY, b"{}", None, allow_unsigned=True)


def test_other_cell_and_clock_window() -> None:
    check_cell(KIND, "cell1", "cell1")
    with pytest.raises(Refused, match="is for cell 'cell2', this is 'cell1'"):
        check_cell(KIND, "cell2", "cell1")
    check_window(KIND, 1000.0 + 30.0, 1000.0, 30.0)
    for wall in (1000.0 + 30.5, 1000.0 - 30.5, math.nan, math.inf):
        with pytest.raises(Refused, match="off the monitor's clock"):
            check_window(KIND, wall, 1000.0, 30.0)


def test_request_ids_refuse_a_replay_and_stay_bounded() -> None:
    ids = RequestIds(window_s=30.0)
    ids.use(KIND, "a", 1000.0)
    with pytest.raises(Refused, match="'a' was already used"):
        ids.use(KIND, "a", 1059.0)  # within 2 x window: still remembered
    ids.use(KIND, "a", 1000.0 + 61.0 + 59.0)  # forgotten after 2 x window (then refused by it)
    for i in range(MAX_REMEMBERED + 50):  # each newer than the ones forgotten for room
        ids.use(KIND, f"r{i}", 2000.0 + i * 1e-3)
    with pytest.raises(Refused, match="no longer remembers"):  # older than the forgotten
        ids.use(KIND, "late", 2000.0)
    assert len(ids._seen) <= MAX_REMEMBERED + 1


def test_the_verify_budget_allows_a_burst_then_its_rate() -> None:
    from monitor.wire.verify_budget import VerifyBudget

    budget = VerifyBudget(per_s=4.0)
    assert sum(budget.take(100.0) for _ in range(50)) == 4  # the burst, then nothing
    assert not budget.take(100.125)  # half a token
    assert budget.take(100.25) and not budget.take(100.25)  # one token a 0.25 s
    assert sum(budget.take(200.0) for _ in range(50)) == 4  # refilled to the burst, no more


GATES = {  # each SignedGate, its refusal, a payload builder and its own words for another boot
    "mute": (MuteGate, MuteRefused, lambda **kw: mute_payload("anna", "z1", 10, **kw),
             "request names monitor boot 'b0', this monitor runs boot 'b1' (a request from "
             "before a restart?)"),
    "accept": (AcceptGate, AcceptRefused, lambda **kw: accept_payload("anna", "cam0", "z1", **kw),
               "request names monitor boot 'b0', this monitor runs boot 'b1' (a request from "
               "before a restart?)"),
    "apply": (ApplyGate, ApplyRefused, lambda **kw: apply_payload("anna", "ab" * 16, **kw),
              "zone apply made for boot 'b0', this monitor runs boot 'b1' (a request from "
              "before a restart)"),
}


@pytest.mark.parametrize("name", sorted(GATES))
def test_each_signed_gate_checks_in_one_order_with_its_own_words(name) -> None:
    gate_class, refused, payload_of, other_boot = GATES[name]
    signer, signers = _signer()
    gate = gate_class(signers, "cell1", KEY, window_s=30.0)

    def check(payload: bytes, signature: bytes | None = None, wall_now: float = 1000.0):
        sig = signer.sign(KEY, payload) if signature is None else signature
        return gate.check(payload, sig, 5.0, wall_now, boot="b1")

    # signature before cell, cell before boot, boot before the clock, the clock before replay
    bad = payload_of(cell="cell2", boot="b0", wall=900.0, request_id="r1")
    with pytest.raises(refused, match="signature does not match"):
        check(bad, _signer()[0].sign(KEY, bad))
    with pytest.raises(refused, match="is for cell 'cell2', this is 'cell1'"):
        check(bad)
    with pytest.raises(refused) as boot:
        check(payload_of(cell="cell1", boot="b0", wall=900.0, request_id="r1"))
    assert str(boot.value) == other_boot
    with pytest.raises(refused, match="off the monitor's clock"):
        check(payload_of(cell="cell1", boot="b1", wall=900.0, request_id="r1"))
    ok = payload_of(cell="cell1", boot="b1", wall=1000.0, request_id="r1")
    request = check(ok)
    assert (request.operator, request.request_id) == ("anna", "r1")
    with pytest.raises(refused, match="'r1' was already used"):
        check(ok)
