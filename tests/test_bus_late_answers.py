"""A mute or reset the monitor answered "not judged in time" is never applied later.

The bus answers an operator's query once its deadline (``reset_answer_s``) has passed without
the pipeline taking the request (a stalled or loaded loop). The request must go with that
answer: a mute applied after its operator read REFUSED would leave a protective zone muted
that nobody believes muted, and a reset decided after "not decided" would release a latch its
operator believes still holds. A request the pipeline has taken is answered with its outcome,
however late. Real SafetyBus, real Zenoh sessions on 127.0.0.1.
"""

from __future__ import annotations

import threading
import time

import pytest

from monitor.bus.session import BusKeys
from monitor.cases.mute_requests import mute_payload, request_mute
from monitor.cases.muting import MuteOutcome
from monitor.policy import Command, Latch, ResetOutcome
from monitor.wire.resets import request_reset, reset_payload
from tests.helpers import wait_for
from tests.processes import bus_with_operator

CELL = "late"
ANSWER_S = 0.5  # the bus's deadline for the pipeline's answer (reset_answer_s)


@pytest.fixture()
def bus_and_operator(tmp_path):
    with bus_with_operator(tmp_path, CELL, "mon-late", ANSWER_S) as (bus, session, anna):
        yield bus, session, anna, BusKeys.of(f"workcell/{CELL}/")


def _ask(ask, *args) -> tuple[threading.Thread, list]:
    """The operator's query in a thread (it blocks until the answer or its 10 s timeout)."""
    answers: list = []
    asker = threading.Thread(target=lambda: answers.append(ask(*args, timeout=10.0)))
    asker.start()
    return asker, answers


def _mute(bus, session, key, keys, zone: str):
    payload = mute_payload("anna", zone, 10, cell=CELL, boot=bus.boot)
    return _ask(request_mute, session, keys.mute, payload, key.sign(keys.mute, payload))


def test_a_mute_answered_not_judged_is_never_applied_and_a_taken_one_is_answered_late(
        bus_and_operator):
    bus, session, key, keys = bus_and_operator
    asker, answers = _mute(bus, session, key, keys, "z-late")
    asker.join(15)  # nobody polls: the bus answers once the deadline passed
    (answer,) = answers
    assert answer is not None and not answer["accepted"], answer
    assert "did not judge this request in time" in answer["reason"]
    time.sleep(0.2)
    assert bus.poll_mutes() == ()  # gone with its answer: a late step never mutes z-late
    assert bus.status()["mutes_waiting"] == 0

    asker, answers = _mute(bus, session, key, keys, "z-taken")
    (taken,) = wait_for(lambda: bus.poll_mutes(), what="the mute request at the bus")
    time.sleep(3 * ANSWER_S)  # past the deadline while the pipeline judges it
    assert asker.is_alive() and answers == []  # not answered "not judged": it is being judged
    bus.answer_mute(MuteOutcome(taken, True, "muted by anna for 10 s"))
    asker.join(15)
    assert answers[0] is not None and answers[0]["accepted"], answers
    assert answers[0]["zone"] == "z-taken"


def _reset(bus, session, key, keys, latch: str):
    payload = reset_payload("anna", cell=CELL, boot=bus.boot, latch=latch)
    return _ask(request_reset, session, keys.reset, payload, key.sign(keys.reset, payload))


def test_a_reset_answered_not_decided_is_never_decided_later_and_older_ones_are_superseded(
        bus_and_operator):
    bus, session, key, keys = bus_and_operator
    latch = "1-0123456789abcdef"
    held = Command("STOP", 0.0, (), 1.0, latched=True,
                   latched_by=Latch("frame_timeout", "no frame", 1.0, nonce=latch))
    bus.publish_command(held)
    asker, answers = _reset(bus, session, key, keys, latch)
    asker.join(15)  # nobody polls: answered once the deadline passed
    (answer,) = answers
    assert answer is not None and not answer["accepted"], answer
    assert "did not decide on this request in time" in answer["reason"]
    time.sleep(0.2)
    assert bus.poll_resets() == []  # gone with its answer: never decided later

    # two waiting at one step: the newest is taken, the older one answered at once
    first, first_answers = _reset(bus, session, key, keys, latch)
    wait_for(lambda: bus.status()["resets_waiting"] == 1, what="the first reset at the bus")
    second, second_answers = _reset(bus, session, key, keys, latch)
    wait_for(lambda: bus.status()["resets_waiting"] == 2, what="the second reset at the bus")
    (newest,) = bus.poll_resets()
    first.join(15)
    assert first_answers[0] is not None and not first_answers[0]["accepted"]
    assert "superseded by a newer request" in first_answers[0]["reason"]
    time.sleep(3 * ANSWER_S)  # past its deadline while the policy decides it
    assert second.is_alive() and second_answers == []
    bus.publish_command(Command("STOP", 0.0, (), 1.0, reset=ResetOutcome(
        "anna", True, "reset accepted", newest.request_id)))  # the policy's outcome, late
    second.join(15)
    assert second_answers[0] is not None and second_answers[0]["accepted"], second_answers
