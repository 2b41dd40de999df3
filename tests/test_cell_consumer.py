"""The consumer rule for several monitors of one cell (monitor.wire.cell_consumer), pure: each role
with its own key and command key; the cell is the most restrictive of all expected roles."""

from __future__ import annotations

import json

import pytest

from monitor.errors import ConfigError
from monitor.wire.busconfig import BusConfig, BusKeys
from monitor.wire.cell_consumer import CellWatchdog, parse_expect
from monitor.wire.signing import load_private_key, load_public_key, new_key_pair

PREFIX = "workcell/c1/"
WALL = 1_000_000.0


@pytest.fixture()
def keys(tmp_path):
    out = {}
    for role in ("monitor-a", "monitor-b", "monitor-c"):
        private, public, _ = new_key_pair(tmp_path / f"{role}.key")
        out[role] = (load_private_key(private), load_public_key(public))
    return out


def _cell(keys, roles=("monitor-a", "monitor-b"), **kw) -> CellWatchdog:
    return CellWatchdog({r: (keys[r][1],) for r in roles}, PREFIX, cell="c1", **kw)


class Monitor:
    """One role's monitor: signed commands on its own key."""

    def __init__(self, role: str, signer, instance: str | None = None, boot: str = "b1") -> None:
        self.role, self.signer, self.boot = role, signer, boot
        self.instance = instance or f"{role}-host"
        self.key = BusKeys.of(PREFIX, role).command
        self.seq = 0

    def send(self, dog: CellWatchdog, now: float, state: str = "RUN", scale: float = 1.0,
             reasons=(), key: str | None = None) -> str | None:
        self.seq += 1
        body = {"schema": "workcell.safety.command/1", "cell": "c1", "seq": self.seq,
                "boot": self.boot, "instance": self.instance, "role": self.role,
                "state": state, "speed_scale": scale, "ttl_ms": 300, "wall": WALL + now,
                "boot_wall": WALL, "reasons": [{"code": c, "message": c} for c in reasons]}
        payload = json.dumps(body).encode()
        key = key or self.key
        return dog.on_command(payload, now, self.signer.sign(key, payload), WALL + now, key)

    def alive(self, dog: CellWatchdog, up: bool = True) -> None:
        dog.on_liveliness(f"{BusKeys.of(PREFIX, self.role).alive}/{self.instance}", up)


def _pair(keys, dog):
    a = Monitor("monitor-a", keys["monitor-a"][0])
    b = Monitor("monitor-b", keys["monitor-b"][0])
    a.alive(dog)
    b.alive(dog)
    return a, b


def test_role_keys_keep_the_single_monitor_keys_and_put_each_role_under_its_name():
    assert BusKeys.of(PREFIX) == BusKeys.of(PREFIX, "")
    assert BusKeys.of(PREFIX).command == "workcell/c1/safety/command"
    k = BusKeys.of(PREFIX, "monitor-a")
    assert k.command == "workcell/c1/safety/monitor-a/command"
    assert k.reset == "workcell/c1/safety/monitor-a/reset"
    assert k.alive == "workcell/c1/safety/alive/monitor-a"
    assert k.pose == "workcell/c1/tracker/pose"  # the tool is the cell's
    with pytest.raises(ConfigError, match=r"bus\.role: .alive. is not a role name"):
        BusConfig(role="alive")
    with pytest.raises(ConfigError, match="key chunk"):
        BusConfig(role="a/b")


def test_the_cell_runs_only_when_every_expected_monitor_says_run(keys):
    dog = _cell(keys)
    a, b = _pair(keys, dog)
    assert a.send(dog, 0.0) is None
    v = dog.verdict(0.01)
    assert v.state == "STOP" and "monitor-b: silence" in v.reason  # b missing, named
    assert b.send(dog, 0.02) is None
    assert dog.verdict(0.03).state == "RUN"
    b.send(dog, 0.05, "SLOW", 0.3, ["warning_zone"])
    v = dog.verdict(0.06)
    assert (v.state, v.speed_scale) == ("SLOW", 0.3) and v.reason.startswith("monitor-b:")
    a.send(dog, 0.07, "STOP", 0.0, ["protective_zone"])
    v = dog.verdict(0.08)
    assert v.state == "STOP" and "monitor-a: STOP protective_zone" in v.reason


def test_a_stale_or_vanished_monitor_is_stop_by_name(keys):
    dog = _cell(keys)
    a, b = _pair(keys, dog)
    a.send(dog, 0.0)
    b.send(dog, 0.0)
    a.send(dog, 0.5)
    v = dog.verdict(0.6)  # b silent for 600 ms > ttl 300
    assert v.state == "STOP" and v.code == "ttl" and v.reason.startswith("monitor-b: silence")
    b.send(dog, 0.65)
    assert dog.verdict(0.7).state == "RUN"
    a.alive(dog, False)  # killed: its token vanishes
    v = dog.verdict(0.71)
    assert v.state == "STOP" and v.reason.startswith("monitor-a: silence: liveliness")


def test_two_instances_of_one_role_are_a_duplicate_named(keys):
    dog = _cell(keys)
    a, b = _pair(keys, dog)
    a2 = Monitor("monitor-a", keys["monitor-a"][0], instance="monitor-a-other", boot="b2")
    a2.alive(dog)
    a.send(dog, 0.0)
    b.send(dog, 0.0)
    v = dog.verdict(0.01)
    assert v.state == "STOP" and v.code == "duplicate_monitor"
    assert v.reason.startswith("monitor-a: duplicate_monitor")


def test_an_unknown_monitor_with_its_own_key_is_stop_named(keys):
    dog = _cell(keys)
    a, b = _pair(keys, dog)
    c = Monitor("monitor-c", keys["monitor-c"][0])
    a.send(dog, 0.0)
    b.send(dog, 0.0)
    assert dog.verdict(0.01).state == "RUN"
    assert c.send(dog, 0.02) == "unknown_monitor"
    v = dog.verdict(0.03)
    assert v.state == "STOP" and v.code == "unknown_monitor" and "monitor-c" in v.reason
    # its token alone (before any command) is enough too
    dog2 = _cell(keys)
    a2, b2 = _pair(keys, dog2)
    a2.send(dog2, 0.0)
    b2.send(dog2, 0.0)
    c.alive(dog2)
    v = dog2.verdict(0.01)
    assert v.state == "STOP" and "monitor-c (live: monitor-c-host)" in v.reason
    c.alive(dog2, False)
    assert dog2.verdict(0.02).state == "RUN"
    # a single-role monitor (no role) on a cell that expects roles is unknown as well
    legacy = Monitor("", keys["monitor-c"][0], instance="old")
    legacy.key = BusKeys.of(PREFIX).command
    assert legacy.send(dog2, 0.03) == "unknown_monitor"
    assert "(no role)" in dog2.verdict(0.04).reason


def test_a_third_monitor_under_an_expected_role_with_its_own_key_counts_nothing_but_is_seen(
        keys):
    """A third monitor configured as monitor-a but signing with its own key: its commands are
    dropped (signature), and its liveliness token makes monitor-a a duplicate."""
    dog = _cell(keys)
    a, b = _pair(keys, dog)
    rogue = Monitor("monitor-a", keys["monitor-c"][0], instance="rogue", boot="b9")
    assert rogue.send(dog, 0.0) == "signature"
    a.send(dog, 0.0)
    b.send(dog, 0.0)
    assert dog.verdict(0.01).state == "RUN"
    rogue.alive(dog)
    assert dog.verdict(0.02).code == "duplicate_monitor"


def test_a_role_cannot_speak_for_another(keys):
    """monitor-a's signature is over monitor-a's key: replayed on monitor-b's key it fails."""
    dog = _cell(keys)
    a, _b = _pair(keys, dog)
    assert a.send(dog, 0.0, key=BusKeys.of(PREFIX, "monitor-b").command) == "signature"
    a.send(dog, 0.0)
    v = dog.verdict(0.01)
    assert v.state == "STOP" and "monitor-b" in v.reason


def test_an_old_recording_of_an_unknown_role_does_not_stop_and_junk_is_dropped(keys):
    dog = _cell(keys)
    a, b = _pair(keys, dog)
    a.send(dog, 0.0)
    b.send(dog, 0.0)
    key = BusKeys.of(PREFIX, "monitor-c").command
    assert dog.on_command(b"junk", 0.0, None, WALL, key) == "invalid"
    old = json.dumps({"schema": "workcell.safety.command/1", "cell": "c1", "seq": 1,
                      "boot": "x", "instance": "y", "state": "RUN", "speed_scale": 1.0,
                      "ttl_ms": 300, "wall": WALL - 3600}).encode()
    assert dog.on_command(old, 0.0, None, WALL, key) == "window"
    assert dog.verdict(0.01).state == "RUN"


def test_parse_expect_names_bad_items(tmp_path):
    _, public, _ = new_key_pair(tmp_path / "a.key")
    got = parse_expect([f"monitor-a={public}"], load_public_key)
    assert list(got) == ["monitor-a"] and len(got["monitor-a"]) == 1
    with pytest.raises(ValueError, match="ROLE=KEYFILE"):
        parse_expect(["monitor-a"], load_public_key)
    with pytest.raises(ValueError, match="not a role name"):
        parse_expect([f"status={public}"], load_public_key)
