"""Issue 31, part 1: refused console requests from the cell network never become incidents,
and their audit lines are bounded and rate-limited (real HTTP through Starlette's test client
against the real app, a real recorder data dir and a real audit file)."""

from __future__ import annotations

import json

from starlette.testclient import TestClient

from monitor.console.app import build_app
from monitor.console.audit import REFUSED_BURST, REFUSED_EVERY_S, AuditLog, RefusalBudget
from monitor.console.logins import LoginGuard, LoginLimits
from monitor.incidents import IncidentIndex
from tests.console_kit import OPERATOR, basic, make_console

SQUARE = [[900, 150], [1200, 150], [1200, 400], [900, 400]]


class Clock:
    """Monotonic seconds the test moves on."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _lines(path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_500_unauthenticated_requests_make_no_incident_and_a_bounded_audit(tmp_path):
    clock = Clock()
    audit = AuditLog(tmp_path / "audit.jsonl", RefusalBudget(clock=clock))
    console = make_console(tmp_path, audit=audit, logins=LoginGuard(clock=clock))
    client = TestClient(build_app(console))
    data_dir = tmp_path / "incidents"
    before = [i.id for i in IncidentIndex(data_dir).list()]
    assert before  # the real recorder's STOP/latch incident with its clip
    zone = "z" * 15_000  # the 15 kB zone id
    body = {"camera": "cam0", "kind": "protective", "points_px": SQUARE}
    headers = [{}, {"authorization": "Bearer " + "x" * 5000}, {"authorization": "Basic !!"},
               basic("m" * 3000, "x")]  # no, foreign, broken, unknown-name credentials
    for k in range(500):
        r = client.put(f"/api/zones/{zone}", json=body, headers=headers[k % len(headers)])
        # refused; the guesses at a name throttle it (test_console_logins.py)
        assert r.status_code in (401, 429), r.text
        assert "not accepted" in r.json()["error"] or "next try" in r.json()["error"]
    assert [i.id for i in IncidentIndex(data_dir).list()] == before  # not one incident
    lines = [e for e in _lines(tmp_path / "audit.jsonl") if e["event"] == "zone_edit"]
    assert len(lines) == REFUSED_BURST  # the rest counted, not written
    throttled = [e for e in _lines(tmp_path / "audit.jsonl")
                 if e["event"] == "login_throttled"]
    assert len(throttled) == 1  # the name's delay: it holds every later guess, none counted
    raw = (tmp_path / "audit.jsonl").read_text().splitlines()
    assert max(len(line) for line in raw) < 1200  # every field cut, the sizes said
    assert lines[0]["result"] == "refused" and lines[0]["zone"].endswith("(15000 characters)")
    assert lines[3]["tried"].endswith("(3000 characters)")  # the name tried, cut
    # after a quiet spell (and the delays) one more line says how many were not written
    clock.now += max(REFUSED_EVERY_S, LoginLimits().max_delay_s)
    client.put("/api/zones/aisle", json=body)
    last = _lines(tmp_path / "audit.jsonl")[-1]
    assert last["refused_unwritten"] == 500 - REFUSED_BURST and last["zone"] == "aisle"
    # an operator's edit is still audited whole and an incident
    ok = client.put("/api/zones/aisle", json=body, headers=basic(OPERATOR, "correct horse "
                                                                            "battery"))
    assert ok.status_code == 200 and ok.json()["incident"]
    assert _lines(tmp_path / "audit.jsonl")[-1]["result"] == "saved"
    assert len(IncidentIndex(data_dir).list()) == len(before) + 1


def test_with_editing_off_refusals_are_403_and_no_incident(tmp_path):
    console = make_console(tmp_path, with_passwords=False)
    client = TestClient(build_app(console))
    before = len(IncidentIndex(tmp_path / "incidents").list())
    for _ in range(50):
        r = client.put("/api/zones/aisle", json={"points_px": SQUARE},
                       headers=basic(OPERATOR, "correct horse battery"))
        assert r.status_code == 403 and "without --passwords" in r.json()["error"]
    assert len(IncidentIndex(tmp_path / "incidents").list()) == before
    assert 1 <= len(_lines(tmp_path / "audit.jsonl")) <= REFUSED_BURST
