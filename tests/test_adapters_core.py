"""The adapters' core: a real signed monitor bus on 127.0.0.1, the consumer rule once in a
Follower, one snapshot per tick for every output (monitor/adapters/)."""

from __future__ import annotations

import json
import threading

import pytest

from monitor.adapters import SafetySnapshot, snapshot_of
from monitor.adapters.follower import Follower, subscribe
from monitor.bus.session import BusConfig, BusKeys, SafetyBus, open_session
from monitor.policy import Command, Reason
from monitor.wire.consumer import COMMAND_SCHEMA, CommandWatchdog, Verdict
from monitor.wire.inbox import Inbox
from monitor.wire.signing import load_private_key, load_public_key, new_key_pair
from tests.helpers import free_port, wait_for

CELL = "ad"
TTL_MS = 300


class Recorder:
    name = "recorder"

    def __init__(self) -> None:
        self.seen: list[SafetySnapshot] = []

    def publish(self, snapshot: SafetySnapshot) -> None:
        self.seen.append(snapshot)

    def close(self) -> None:
        pass


class Broken:
    name = "broken"

    def publish(self, snapshot: SafetySnapshot) -> None:
        raise RuntimeError("the protocol library fell over")

    def close(self) -> None:
        pass


@pytest.fixture()
def monitor_and_follower(tmp_path):
    private, public, _ = new_key_pair(tmp_path / "monitor.key")
    port = free_port()
    cfg = BusConfig(cell=CELL, instance="mon-ad", listen=(f"tcp/127.0.0.1:{port}",),
                    heartbeat_hz=20.0, ttl_ms=TTL_MS, signing_key=str(private))
    keys = BusKeys.of(f"workcell/{CELL}/")
    dog = CommandWatchdog(public_keys=(load_public_key(public),), cell=CELL,
                          key_expr=keys.command)
    inbox = Inbox(64)
    with SafetyBus(cfg) as bus, open_session(BusConfig(
            cell=CELL, instance="adapter", connect=(f"tcp/127.0.0.1:{port}",))) as session:
        entities = subscribe(session, keys, inbox)
        try:
            yield bus, session, keys, Follower(dog, inbox, cameras=("cam0",)), private
        finally:
            for e in entities:
                e.undeclare()


def test_snapshots_follow_the_signed_commands_and_fall_to_stop_on_silence(
        monitor_and_follower):
    bus, _, _, follower, _ = monitor_and_follower
    first = follower.step()
    # STOP before the monitor's first word; on a loaded machine its first heartbeat (the STOP it
    # starts in) may already be in while its liveliness token is not: STOP for either reason
    assert first.state == "STOP" and first.speed_scale == 0.0 and first.counter == 1
    assert first.reason_code in ("no_command", "liveliness", "startup")
    bus.publish_command(Command("SLOW", 0.4, (Reason("warning_zone", "person 1 in W",
                                                     zone_id="W"),)))
    slow = wait_for(lambda: (s := follower.step(0.01)).state == "SLOW" and s)
    assert slow and slow.speed_scale == 0.4 and slow.reason_code == "warning_zone"
    assert slow.zone_id == "W" and slow.instance == "mon-ad" and slow.age_ms is not None
    assert slow.cameras == {"cam0": True}
    bus.publish_command(Command("RUN", 1.0))
    run = wait_for(lambda: (s := follower.step(0.01)).state == "RUN" and s)
    assert run and run.reason_code == "" and run.seq is not None
    counters = [follower.step().counter for _ in range(3)]
    assert counters == sorted(counters) and len(set(counters)) == 3  # the heartbeat moves
    bus.close()  # the monitor is gone: its final STOP, then silence
    stop = wait_for(lambda: (s := follower.step(0.01)).state == "STOP" and s)
    assert stop and stop.speed_scale == 0.0


def test_a_forged_unsigned_run_never_reaches_an_output(monitor_and_follower, tmp_path):
    bus, session, keys, follower, _ = monitor_and_follower
    bus.publish_command(Command("STOP", 0.0, (Reason("protective_zone", "person 1 in P",
                                                     zone_id="P"),)))
    assert wait_for(lambda: follower.step(0.01).reason_code == "protective_zone")
    forger_key, _, _ = new_key_pair(tmp_path / "forger.key")
    forger = load_private_key(forger_key)
    body = {"schema": COMMAND_SCHEMA, "cell": CELL, "instance": "mon-ad", "boot": "forged",
            "seq": 10**6, "state": "RUN", "speed_scale": 1.0, "ttl_ms": 1000}
    for signed in (False, True):  # unsigned, and signed by a key nobody pinned
        payload = json.dumps(body).encode()
        attachment = forger.sign(keys.command, payload) if signed else None
        for _ in range(20):
            session.put(keys.command, payload, attachment=attachment)
    seen = [follower.step(0.02) for _ in range(30)]
    assert all(s.state == "STOP" for s in seen)
    assert follower.dog.rejected  # counted, not followed


def test_a_broken_output_never_silences_the_others(monitor_and_follower):
    bus, _, _, follower, _ = monitor_and_follower
    rec = Recorder()
    stop = threading.Event()
    bus.publish_command(Command("RUN", 1.0))
    runner = threading.Thread(target=follower.run, args=([Broken(), rec], stop, 0.01, 1.0))
    runner.start()
    runner.join(timeout=10)
    assert not runner.is_alive()
    assert len(rec.seen) >= 20 and any(s.state == "RUN" for s in rec.seen)
    assert follower.output_errors["broken"] == len(rec.seen)


@pytest.mark.parametrize("verdict", [
    Verdict("RUN", float("nan"), ""), Verdict("BOGUS", 1.0, ""), Verdict("SLOW", 1.5, ""),
    Verdict("RUN", -0.1, ""),
], ids=["nan", "unknown-state", "scale-above-1", "negative"])
def test_a_verdict_that_cannot_be_is_a_stop_snapshot_never_run(verdict):
    snap = snapshot_of(verdict, 1.0, 1e9, 1, 0.9)
    assert snap.state == "STOP" and snap.speed_scale == 0.0 and snap.state_code == 0


def test_an_overriding_verdict_says_nothing_about_cameras_or_zones():
    cmd = {"state": "RUN", "speed_scale": 1.0, "reasons": [
        {"code": "fault", "fault": "camera_lost", "source": "cam1", "zone_id": "P"}]}
    fresh = snapshot_of(Verdict("RUN", 1.0, "", 5, cmd), 1.0, 1e9, 1, 0.99, ("cam0", "cam1"))
    assert fresh.cameras == {"cam0": True, "cam1": False} and fresh.faults == ("camera_lost",)
    stale = snapshot_of(Verdict("STOP", 0.0, "silence", 5, cmd, "ttl"), 2.0, 1e9, 2, 0.99,
                        ("cam0", "cam1"))
    assert stale.cameras == {"cam0": False, "cam1": False} and stale.zone_id is None
    assert stale.reason_code == "ttl" and stale.age_ms == pytest.approx(1010.0)


def test_a_step_reads_only_what_waited_so_a_flood_never_starves_the_outputs():
    """The Zenoh threads may refill the inbox as fast as it is read: a step takes at most
    what was there when it began, then hands a snapshot on (and the loop sees a stop)."""
    inbox = Inbox(10_000)
    dog = CommandWatchdog(cell=CELL, require_liveliness=False)
    follower = Follower(dog, inbox)

    class Refilling:
        """An inbox that gets a new forged command for every one read (a flood)."""

        def get(self, timeout: float):
            item = inbox.get(timeout)
            inbox.put("command", ("command", b"{}", None, 0.0, 0.0))
            return item

        def __len__(self) -> int:
            return len(inbox)

    for _ in range(50):
        inbox.put("command", ("command", b"{}", None, 0.0, 0.0))
    follower.inbox = Refilling()
    snap = follower.step()  # returns at all: the old drain read the flood forever
    assert snap.state == "STOP" and 50 <= sum(dog.rejected.values()) <= 52
