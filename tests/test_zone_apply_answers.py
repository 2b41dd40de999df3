"""Whose answer `monitor zones apply` believes: the monitor signs its zone-apply answers
(refused at the bus, refused or applied by the loop) and names the request it answers, and
`monitor zones apply --monitor-key` believes nothing else.

Before, a rogue queryable on the apply key answering "zone set ... in force" at once made the
operator believe the new (say, larger) protective zone was watched while the monitor still
decided on the old one. Real SafetyBus with the service's own zone-apply queryable
(``monitor.service.zone_swap.ZoneApplies``), real Zenoh sessions on 127.0.0.1, `monitor zones
apply` as a real process; this test plays the safety loop's part (``answer``, as
``LiveZones.poll`` does).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

from monitor.bus.session import BusConfig, BusKeys, open_session
from monitor.cases.zone_apply import APPLY_ANSWER_SCHEMA, apply_payload, request_apply
from monitor.config import demo_cell_path
from monitor.service.zone_swap import ZoneApplies, answer
from monitor.wire.answers import request_digest
from monitor.wire.signing import load_private_key, load_public_key, new_key_pair
from tests.processes import bus_with_operator

CELL = "zans"
HASH = "0" * 64


def test_a_refusal_at_the_bus_is_signed_and_names_the_request(tmp_path):
    carl, _, _ = new_key_pair(tmp_path / "carl.key")  # not listed
    with bus_with_operator(tmp_path, CELL, "mon-zans", 2.0) as (bus, session, _):
        applies = ZoneApplies(bus)
        try:
            keys = BusKeys.of(f"workcell/{CELL}/")
            payload = apply_payload("anna", HASH, cell=CELL, boot=bus.boot)
            signature = load_private_key(carl).sign(keys.zones_apply, payload)
            trusted = (load_public_key(tmp_path / "monitor.key.pub"),)
            # on a loaded host the first query may leave before the route to the monitor's
            # queryable exists (no answer at all): ask again until a ceiling; an unsigned or
            # wrong answer is None every time, so the test still fails on one
            deadline = time.monotonic() + 30
            got = None
            while got is None and time.monotonic() < deadline:
                got = request_apply(session, keys.zones_apply, payload, signature, 5, trusted)
        finally:
            applies.close()
    assert got is not None, "the monitor's refusal was not signed for this request"
    assert (got["accepted"], got["request"], got["instance"], got["boot"],
            got["signed_by"]) == (False, request_digest(payload), "mon-zans", bus.boot,
                                  bus.public_key)
    assert "signature does not match" in got["reason"]


def _apply_against_a_rogue(tmp_path, *extra: str) -> tuple[str, str, int]:
    rogue_key, _, _ = new_key_pair(tmp_path / "rogue.key")
    with bus_with_operator(tmp_path, CELL, "mon-zans", 2.0) as (bus, _, _):
        applies = ZoneApplies(bus)
        keys = BusKeys.of(f"workcell/{CELL}/")
        rogue_signer = load_private_key(rogue_key)

        def lie(query) -> None:
            body = {"schema": APPLY_ANSWER_SCHEMA, "accepted": True, "operator": "anna",
                    "reason": f"zone set {HASH} in force", "instance": "mon-zans"}
            query.reply(keys.zones_apply, json.dumps(body).encode())  # unsigned
            own = json.dumps({**body, "request": request_digest(
                query.payload.to_bytes())}).encode()
            query.reply(keys.zones_apply, own,
                        attachment=rogue_signer.sign(keys.zones_apply + "/answer", own))

        port = bus.config.listen[0].rsplit(":", 1)[1]
        try:
            with open_session(BusConfig(cell=CELL, instance="rogue",
                                        connect=(f"tcp/127.0.0.1:{port}",))) as rogue:
                rogue.declare_queryable(keys.zones_apply, lie)
                time.sleep(0.3)
                proc = subprocess.Popen(
                    [sys.executable, "-m", "monitor", "zones", "apply", "--operator", "anna",
                     "--key", str(tmp_path / "anna.key"), "--zones", str(demo_cell_path()),
                     "--cell", CELL, "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "20",
                     *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                queued: list = []
                started = time.monotonic()
                while not queued and time.monotonic() - started < 60 and proc.poll() is None:
                    queued = applies.take()[0]
                    time.sleep(0.01)
                for req, query, digest in queued:  # the loop's part: the file changed
                    answer(bus, query, digest, {"accepted": False, "operator": req.operator,
                                                "request_id": req.request_id,
                                                "reason": "the file changed after you signed"})
                stdout, stderr = proc.communicate(timeout=90)
        finally:
            applies.close()
    return stdout, stderr, proc.returncode


def test_a_rogue_responders_zones_applied_is_not_believed_with_the_monitor_key(tmp_path):
    (tmp_path / "a").mkdir()
    stdout, stderr, code = _apply_against_a_rogue(tmp_path / "a")
    assert code == 0 and "zones applied by anna" in stdout, (stdout, stderr)  # the attack
    assert "NOT authenticated" in stderr

    (tmp_path / "b").mkdir()
    stdout, stderr, code = _apply_against_a_rogue(
        tmp_path / "b", "--monitor-key", str(tmp_path / "b" / "monitor.key.pub"))
    assert code == 1, (stdout, stderr)
    assert stdout == "zone apply by anna REFUSED: the file changed after you signed\n"
    assert "2 answers ignored (1 unsigned, 1 not signed by --monitor-key)" in stderr, stderr
