"""Whose answer `monitor case select` believes: with the service's wiring
(``CaseReceiver.for_bus(..., bus.signed_answer)``) the monitor signs its selection answers and
names the request, and `monitor case select --monitor-key` believes nothing else: a rogue
queryable on the case key answering "verified" at once is ignored and the monitor's refusal is
printed. Real SafetyBus and receiver, real Zenoh sessions on 127.0.0.1, the CLI as a process.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from monitor.bus.session import BusConfig, SafetyBus, open_session
from monitor.cases.receiver import CASE_ANSWER_SCHEMA, CaseReceiver, case_key, request_case
from monitor.cases.requests import case_payload
from monitor.cases.sets import CasePlan, ZoneSet
from monitor.wire.answers import request_digest
from monitor.wire.signing import load_private_key, load_public_key, new_key_pair
from tests.helpers import free_port

CELL = "cans"
PLAN = CasePlan((ZoneSet("A", frozenset({"a"})), ZoneSet("B", frozenset({"b"}))), default="A")


def _monitor_with_selector_robot(tmp_path) -> tuple[Path, BusConfig, int]:
    """The monitor's key pair, a selectors file listing robot (its key pair beside it) and the
    monitor's bus config that trusts it: (robot's private key, the config, the bus port)."""
    private, _, _ = new_key_pair(tmp_path / "monitor.key")
    robot_key, _, robot = new_key_pair(tmp_path / "robot.key")
    (tmp_path / "selectors").write_text(f"robot {robot}\n")
    port = free_port()
    cfg = BusConfig(cell=CELL, instance="mon-cans", listen=(f"tcp/127.0.0.1:{port}",),
                    signing_key=str(private), selectors_file=str(tmp_path / "selectors"))
    return robot_key, cfg, port


def _select_against_a_rogue(tmp_path, *extra: str) -> tuple[str, str, int]:
    _, cfg, port = _monitor_with_selector_robot(tmp_path)  # robot is listed
    mallory, _, _ = new_key_pair(tmp_path / "mallory.key")  # not listed: the monitor refuses
    with SafetyBus(cfg) as bus, \
            CaseReceiver.for_bus(bus.session, bus.config, PLAN, bus.signed_answer), \
            open_session(BusConfig(cell=CELL, instance="rogue",
                                   connect=(f"tcp/127.0.0.1:{port}",))) as rogue:
        key = case_key(bus.config.key_prefix)
        rogue.declare_queryable(key, lambda q: q.reply(key, json.dumps(
            {"schema": CASE_ANSWER_SCHEMA, "accepted": True, "set": "B", "seq": 1,
             "reason": "verified; the switch follows the zone file's rules"})))
        time.sleep(0.3)
        proc = subprocess.run(
            [sys.executable, "-m", "monitor", "case", "select", "B", "--selector", "robot",
             "--key", str(mallory), "--cell", CELL, "--connect", f"tcp/127.0.0.1:{port}",
             "--timeout", "10", *extra], capture_output=True, text=True, timeout=60)
    return proc.stdout, proc.stderr, proc.returncode


def test_a_rogue_responders_verified_is_not_believed_with_the_monitor_key(tmp_path):
    # the rogue and the monitor both answer at once (the monitor refuses mallory's signature):
    # whichever comes first, only the monitor's signed refusal is believed
    stdout, stderr, code = _select_against_a_rogue(
        tmp_path, "--monitor-key", str(tmp_path / "monitor.key.pub"))
    assert code == 1 and "REFUSED" in stdout and "signature" in stdout, (stdout, stderr)
    assert "NOT authenticated" not in stderr


def test_selection_answers_are_signed_and_name_the_request(tmp_path):
    robot_key, cfg, port = _monitor_with_selector_robot(tmp_path)
    with SafetyBus(cfg) as bus, \
            CaseReceiver.for_bus(bus.session, bus.config, PLAN, bus.signed_answer), \
            open_session(BusConfig(cell=CELL, instance="robot",
                                   connect=(f"tcp/127.0.0.1:{port}",))) as robot_session:
        key = case_key(bus.config.key_prefix)
        payload = case_payload("robot", "B", 1, cell=CELL)
        answer = request_case(robot_session, key, payload,
                              load_private_key(robot_key).sign(key, payload), 10,
                              (load_public_key(tmp_path / "monitor.key.pub"),))
    assert answer is not None, "the monitor's answer was not signed for this request"
    assert answer["accepted"] and answer["set"] == "B" and answer["signed_by"] == \
        bus.public_key
    assert answer["request"] == request_digest(payload) and answer["instance"] == "mon-cans"
