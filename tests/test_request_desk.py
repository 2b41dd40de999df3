"""The bus's desk of signed requests the pipeline judges (``monitor.wire.request_desk``): mutes
and acceptances of objects share it, each kind with its own words.

Pins what the operators and consumers see of each kind: a refusal at the bus is answered at
once with the gate's reason, counted in the status and alerted under the kind's own alert name
and wording; a judged one is answered with what that kind's judgement adds; the answers of both
kinds are signed by the monitor and name the request and the monitor (``monitor mute`` or
``monitor objects accept --monitor-key`` believe nothing else; tests/test_mute_answers.py).
Real SafetyBus, real Zenoh sessions on 127.0.0.1.
"""

from __future__ import annotations

import json
import threading
import time

import pytest

from monitor.bus.session import BusKeys
from monitor.cases.mute_requests import MUTE_ANSWER_SCHEMA, mute_payload, request_mute
from monitor.cases.muting import Mute, MuteOutcome
from monitor.wire.answers import request_answer, request_digest
from monitor.wire.object_accepts import ACCEPT_ANSWER_SCHEMA, AcceptOutcome, accept_payload
from monitor.wire.signing import load_private_key, load_public_key, new_key_pair
from tests.helpers import wait_for
from tests.processes import bus_with_operator

CELL = "desk"
ANSWER_S = 0.5


@pytest.fixture()
def desk_bus(tmp_path):
    carl, _, _ = new_key_pair(tmp_path / "carl.key")  # not listed: signs nothing valid
    with bus_with_operator(tmp_path, CELL, "mon-desk", ANSWER_S) as (bus, session, anna):
        alerts: list[dict] = []
        keys = BusKeys.of(f"workcell/{CELL}/")
        session.declare_subscriber(keys.alert, lambda s: alerts.append(
            json.loads(s.payload.to_bytes())))
        yield (bus, session, keys, anna, load_private_key(carl),
               (load_public_key(tmp_path / "monitor.key.pub"),), alerts)


def _ask(ask, *args, **kwargs) -> tuple[threading.Thread, list]:
    answers: list = []
    asker = threading.Thread(target=lambda: answers.append(ask(*args, timeout=10.0, **kwargs)))
    asker.start()
    return asker, answers


def test_a_refusal_at_the_bus_has_each_kinds_answer_alert_and_count(desk_bus):
    bus, session, keys, _, carl, monitor_keys, alerts = desk_bus
    mute = mute_payload("anna", "z1", 10, cell=CELL, boot=bus.boot)
    answer = request_mute(session, keys.mute, mute, carl.sign(keys.mute, mute), 10,
                          monitor_keys)
    assert answer is not None and answer.pop("signed_by").startswith("ed25519:")
    assert answer == {"schema": MUTE_ANSWER_SCHEMA, "accepted": False, "stage": "bus",
                      "reason": "signature does not match operator 'anna'", "operator": "anna",
                      "instance": "mon-desk", "boot": bus.boot, "request": request_digest(mute)}

    accept = accept_payload("anna", "cam0", "z1", cell=CELL, boot=bus.boot)
    answer = request_answer(session, keys.objects_accept, accept,
                            carl.sign(keys.objects_accept, accept), 10, monitor_keys)
    assert answer is not None and answer.pop("signed_by").startswith("ed25519:")
    assert answer == {"schema": ACCEPT_ANSWER_SCHEMA, "accepted": False, "stage": "bus",
                      "reason": "signature does not match operator 'anna'", "operator": "anna",
                      "instance": "mon-desk", "boot": bus.boot,
                      "request": request_digest(accept)}

    wait_for(lambda: {"mute_refused", "object_accept_refused"}
             <= {a["kind"] for a in alerts}, 10, "both refusals alerted")
    messages = {a["kind"]: a["message"] for a in alerts}
    assert messages["mute_refused"] == ("mute in the name of anna refused by the bus: "
                                        "signature does not match operator 'anna'")
    assert messages["object_accept_refused"] == (
        "object acceptance in the name of anna refused by the bus: signature does not match "
        "operator 'anna'")
    status = bus.status()
    assert (status["mutes_refused"], status["object_accepts_refused"]) == (1, 1)
    assert (status["mutes_accepted"], status["objects_accepted"]) == (0, 0)


def test_a_judged_request_is_answered_with_what_its_kind_adds(desk_bus):
    bus, session, keys, anna, _, monitor_keys, _ = desk_bus
    mute = mute_payload("anna", "z1", 10, cell=CELL, boot=bus.boot)
    asker, answers = _ask(request_mute, session, keys.mute, mute, anna.sign(keys.mute, mute),
                          monitor_keys=monitor_keys)
    (req,) = wait_for(lambda: bus.poll_mutes(), what="the mute at the bus")
    bus.answer_mute(MuteOutcome(req, True, "muted", Mute(
        "z1", "anna", req.time, req.time + 10.0, 60.0, "warning", 0.5, req.request_id)))
    asker.join(15)
    (answer,) = answers
    assert answer is not None and answer.pop("signed_by").startswith("ed25519:")
    assert (answer.pop("duration_s"), answer.pop("ends_in_s")) == pytest.approx((10.0, 10.0))
    assert answer == {"schema": MUTE_ANSWER_SCHEMA, "accepted": True, "stage": "pipeline",
                      "reason": "muted", "request_id": req.request_id, "zone": "z1",
                      "instance": "mon-desk", "boot": bus.boot, "request": request_digest(mute)}

    accept = accept_payload("anna", "cam0", "z1", cell=CELL, boot=bus.boot, note="crate")
    asker, answers = _ask(request_answer, session, keys.objects_accept, accept,
                          anna.sign(keys.objects_accept, accept), monitor_keys=monitor_keys)
    (req,) = wait_for(lambda: bus.poll_accepts(), what="the acceptance at the bus")
    assert (req.operator, req.camera, req.zone, req.note) == ("anna", "cam0", "z1", "crate")
    bus.answer_accept(AcceptOutcome(req, True, "1 object accepted", ({"camera": "cam0"},)))
    asker.join(15)
    (answer,) = answers
    assert answer is not None and answer.pop("signed_by").startswith("ed25519:")
    assert answer == {"schema": ACCEPT_ANSWER_SCHEMA, "accepted": True, "stage": "pipeline",
                      "reason": "1 object accepted", "request_id": req.request_id,
                      "camera": "cam0", "zone": "z1", "objects": [{"camera": "cam0"}],
                      "instance": "mon-desk", "boot": bus.boot,
                      "request": request_digest(accept)}
    status = bus.status()
    assert (status["mutes_accepted"], status["objects_accepted"]) == (1, 1)


def test_an_acceptance_not_taken_in_time_is_answered_not_judged_and_dropped(desk_bus):
    bus, session, keys, anna, _, monitor_keys, _ = desk_bus
    accept = accept_payload("anna", "cam0", "z1", cell=CELL, boot=bus.boot)
    asker, answers = _ask(request_answer, session, keys.objects_accept, accept,
                          anna.sign(keys.objects_accept, accept), monitor_keys=monitor_keys)
    asker.join(15)  # nobody polls: the heartbeat answers once the deadline passed
    (answer,) = answers
    assert answer is not None and not answer["accepted"] and answer["stage"] == "bus"
    assert answer["reason"] == ("the monitor did not judge this request in time "
                                "(pipeline stalled?)")
    assert answer["request"] == request_digest(accept)
    time.sleep(0.2)
    assert bus.poll_accepts() == ()  # gone with its answer: never judged later
