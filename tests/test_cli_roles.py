"""`--role` on `monitor status`, `monitor mute` and `monitor zones apply`: on a cell watched by
two monitors (monitor-a, monitor-b; each a Zenoh peer on 127.0.0.1 answering on its own role's
keys), each command reaches only the named role's monitor, signs for that role's key and names
the role in its answer; without --role the one-line error names the roles to pass."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from monitor.bus.session import BusConfig, BusKeys, open_session
from monitor.wire.signing import load_public_key, new_key_pair, verify
from tests.helpers import assert_one_line_error, free_port, run_here

ROLES = ("monitor-a", "monitor-b")
ZONES = Path(__file__).resolve().parents[1] / "zones" / "demo-cell.yaml"


class FakeMonitor:
    """A monitor's request side on its role's keys: status, mute and zones apply queryables
    that record every query (key, payload, signature) and accept."""

    def __init__(self, role: str) -> None:
        self.role, self.port = role, free_port()
        self.keys = BusKeys.of("workcell/rl/", role)
        self.queries: list[tuple[str, bytes, bytes | None]] = []
        self.session = open_session(BusConfig(cell="rl", instance=role,
                                              listen=(f"tcp/127.0.0.1:{self.port}",)))
        self.queryables = [self.session.declare_queryable(
            key, lambda query, key=key: self._on_query(key, query))
            for key in (self.keys.status, self.keys.mute, self.keys.zones_apply)]

    def _on_query(self, key: str, query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        signature = query.attachment.to_bytes() if query.attachment is not None else None
        self.queries.append((str(query.key_expr), payload, signature))
        if key == self.keys.status:
            body = {"boot": f"boot-{self.role}", "cell": "rl", "role": self.role,
                    "state": "RUN", "instance": self.role, "zones_file": str(ZONES)}
        else:
            body = {"accepted": True, "reason": f"done by {self.role}"}
        query.reply(key, json.dumps(body).encode())

    def asked(self, key: str) -> list[tuple[str, bytes, bytes | None]]:
        return [q for q in self.queries if q[0] == key]

    def close(self) -> None:
        for q in self.queryables:
            q.undeclare()
        self.session.close()


@pytest.fixture
def cell():
    monitors = {role: FakeMonitor(role) for role in ROLES}
    try:
        yield monitors
    finally:
        for m in monitors.values():
            m.close()


def _run(monitors: dict, *argv: str, timeout: float = 5.0) -> subprocess.CompletedProcess:
    connect = [a for m in monitors.values() for a in ("--connect", f"tcp/127.0.0.1:{m.port}")]
    return subprocess.run([sys.executable, "-m", "monitor", *argv, "--cell", "rl", *connect,
                           "--timeout", f"{timeout:g}"], capture_output=True, text=True, timeout=60)


def test_status_of_each_named_role_and_only_of_those(cell):
    both = _run(cell, "status", "--json", "--role", "monitor-a", "--role", "monitor-b")
    assert both.returncode == 0, both.stderr
    lines = both.stdout.splitlines()
    assert lines[0] == "monitor-a:" and "monitor-b:" in lines
    split = lines.index("monitor-b:")
    assert json.loads("\n".join(lines[1:split]))["role"] == "monitor-a"
    assert json.loads("\n".join(lines[split + 1:]))["role"] == "monitor-b"

    for m in cell.values():
        m.queries.clear()
    one = _run(cell, "status", "--json", "--role", "monitor-b")
    assert one.returncode == 0, one.stderr
    assert json.loads(one.stdout.split("\n", 1)[1])["instance"] == "monitor-b"
    assert cell["monitor-b"].asked(cell["monitor-b"].keys.status)
    assert cell["monitor-a"].queries == []

    # a role nobody runs: named, exit 2, the others still shown
    typo = _run(cell, "status", "--json", "--role", "monitor-a", "--role", "monitor-c",
                timeout=2.0)
    assert typo.returncode == 2, typo.stderr
    assert "monitor-c: NO ANSWER on workcell/rl/safety/monitor-c/status" in typo.stdout
    assert '"role": "monitor-a"' in typo.stdout


def test_without_role_on_a_cell_with_roles_the_error_names_them(cell):
    out = _run(cell, "status", timeout=2.0)
    assert_one_line_error(out, "no monitor answered on workcell/rl/safety/status",
                          "this cell has monitors monitor-a, monitor-b: pass --role")


def test_mute_reaches_only_the_named_role_signed_for_its_key(cell, tmp_path):
    private, public, _ = new_key_pair(tmp_path / "anna.key")
    out = _run(cell, "mute", "robot-protective", "--for", "30s", "--operator", "anna",
               "--key", str(private), "--role", "monitor-b")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == ("monitor-b: mute of zone robot-protective by anna accepted: "
                                  "done by monitor-b")
    b, a = cell["monitor-b"], cell["monitor-a"]
    (key, payload, signature), = b.asked(b.keys.mute)
    assert key == "workcell/rl/safety/monitor-b/mute"
    assert json.loads(payload)["boot"] == "boot-monitor-b"  # b's status was read, not a's
    # signed for b's key: the same request replayed to monitor-a fails its signature check
    assert verify(load_public_key(public), b.keys.mute, payload, signature)
    assert not verify(load_public_key(public), a.keys.mute, payload, signature)
    assert a.queries == []

    silent = _run(cell, "mute", "robot-protective", "--for", "30s", "--operator", "anna",
                  "--key", str(private), timeout=2.0)
    assert_one_line_error(silent, "monitor mute: no monitor answered on "
                          "workcell/rl/safety/status", "monitor-a, monitor-b: pass --role")
    typo = _run(cell, "mute", "robot-protective", "--for", "30s", "--operator", "anna",
                "--key", str(private), "--role", "monitor-c", timeout=2.0)
    assert_one_line_error(typo, "safety/monitor-c/status", "cell 'rl' are monitor-a, "
                          "monitor-b: check --role")
    assert a.asked(a.keys.mute) == [] and len(b.asked(b.keys.mute)) == 1


def test_zones_apply_reaches_only_the_named_role(cell, tmp_path):
    private, public, _ = new_key_pair(tmp_path / "anna.key")
    out = _run(cell, "zones", "apply", "--operator", "anna", "--key", str(private),
               "--zones", str(ZONES), "--role", "monitor-a")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("monitor-a: zones applied by anna: done by monitor-a")
    a, b = cell["monitor-a"], cell["monitor-b"]
    (key, payload, signature), = a.asked(a.keys.zones_apply)
    assert key == "workcell/rl/safety/monitor-a/zones/apply"
    assert json.loads(payload)["boot"] == "boot-monitor-a"
    assert verify(load_public_key(public), a.keys.zones_apply, payload, signature)
    assert b.queries == []

    silent = _run(cell, "zones", "apply", "--operator", "anna", "--key", str(private),
                  "--zones", str(ZONES), timeout=2.0)
    assert_one_line_error(silent, "this cell has monitors monitor-a, monitor-b: pass --role")


def test_a_role_that_is_no_role_name_is_refused_before_anything_is_sent():
    for command in (["status"], ["mute", "z", "--for", "1s", "--operator", "anna"],
                    ["zones", "apply", "--operator", "anna"]):
        for role, says in (("safety/x", "key chunk"), ("status", "is not a role name")):
            out = run_here(*command, "--role", role)
            assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
            assert "--role" in out.stderr and says in out.stderr, out.stderr
