"""Hand-over holds on a real Zenoh bus (tcp/127.0.0.1): attacks on the *timing* of a peer's
genuine, signed holds messages (monitor/bus/holds.py, docs/consumer.md "Trust")."""

from __future__ import annotations

import contextlib
import json
import os
import threading
import time
from collections.abc import Iterator

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from monitor.bus.holds import HoldsGate, HoldsLink, HoldsSender, holds_payload
from monitor.bus.session import BusConfig, SafetyBus, open_session
from monitor.config import demo_cell_path
from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig
from monitor.tracking.handover import Entry, HandoverConfig
from monitor.wire.busconfig import BusKeys
from monitor.wire.signing import Signer
from monitor.zones import load_cell
from tests.helpers import free_port, wait_for

KEY_A, KEY_B = Ed25519PrivateKey.generate(), Ed25519PrivateKey.generate()


@contextlib.contextmanager
def _monitor_b(detector) -> Iterator[tuple[int, HoldsLink]]:
    """monitor-b's bus on a free loopback port and its holds link expecting monitor-a."""
    port = free_port()
    cfg = BusConfig(cell="ho", role="monitor-b", instance="mon-b",
                    listen=(f"tcp/127.0.0.1:{port}",), heartbeat_hz=20.0)
    pipe = Pipeline(detector, "cam0", PolicyConfig(), load_cell(demo_cell_path()))
    with SafetyBus(cfg) as bus:
        link = HoldsLink(bus, pipe, HandoverConfig(peer_timeout_s=1.0),
                         {"monitor-a": KEY_A.public_key()}, Signer(KEY_B))
        try:
            yield port, link
        finally:
            link.close()


def _meet(session, key: str) -> None:
    """Until monitor-b's holds subscriber is matched (the sessions met): none sent before."""
    pub = session.declare_publisher(key)
    wait_for(lambda: pub.matching_status.matching, what="monitor-b's holds subscriber")
    pub.undeclare()


def _feed(port: int, late_s: float, seconds: float = 1.6) -> None:
    """Monitor-a's genuine holds messages (its key, growing seq, 20 Hz), each ``late_s``
    behind the wall clock: what a man in the middle who holds the stream back delivers."""
    cfg = BusConfig(cell="ho", connect=(f"tcp/127.0.0.1:{port}",), instance="mitm")
    key = BusKeys.of("workcell/ho/", "monitor-a").holds
    signer = Signer(KEY_A)
    with open_session(cfg) as session:
        _meet(session, key)
        end, seq = time.monotonic() + seconds, 0
        while time.monotonic() < end:
            seq += 1
            payload = holds_payload("ho", "monitor-a", "boot-a", seq, time.time() - late_s, ())
            session.put(key, payload, attachment=signer.sign(key, payload))
            time.sleep(0.05)


@pytest.mark.parametrize(("late_s", "silent"), [(0.0, False), (3.0, True)],
                         ids=["on-time", "held-back-3s"])
def test_a_peer_stream_held_back_seconds_is_silent_not_all_clear(detector, late_s, silent):
    """The attack: someone on the path holds monitor-a's signed holds messages back 3 s and
    hands them on in order. Each is genuine, in sequence and inside the 5 s clock window, so
    the first version counted the peer as heard: a person who left A's view toward B's zone
    reached B's monitor 3 s late while it said RUN. A message is now heard as of when it was
    sent: a stream 3 s late is a ``handover_silent`` STOP."""
    with _monitor_b(detector) as (port, link):
        _feed(port, late_s)
        assert link.gate.counts() == {}  # every message verified and taken
        faults = [f for f in link.faults() if f.name == "handover_silent"]
    assert bool(faults) == silent, faults
    if silent:
        assert faults[0].stop and "monitor-a" in faults[0].reason


def test_a_signed_message_with_a_nan_wall_time_is_outside_the_window():
    """json reads NaN: ``abs(NaN - now) > window`` is False, so the first version took a
    message with ``"wall": NaN`` as inside any clock window (and as heard now). NaN is now
    refused before any field is read (monitor/wire/payload.py): invalid, never heard."""
    gate = HoldsGate("ho", "workcell/ho/", "monitor-b", {"monitor-a": KEY_A.public_key()})
    key = BusKeys.of("workcell/ho/", "monitor-a").holds
    body = json.loads(holds_payload("ho", "monitor-a", "b", 1, 1000.0,
                                    (Entry(3, "departure", (4.0, 0.0), 1000.0),)))
    body["wall"] = float("nan")
    payload = json.dumps(body).encode()
    assert gate.check(key, payload, Signer(KEY_A).sign(key, payload), 0.0, 1000.0) is None
    assert gate.counts() == {"invalid": 1} and "NaN" in gate.last_invalid


def _feed_boots(port: int, boots: list[str], each_s: float = 0.5) -> None:
    """Monitor-a's genuine holds messages, on time, first of one run then of the next."""
    cfg = BusConfig(cell="ho", connect=(f"tcp/127.0.0.1:{port}",), instance="peer")
    key = BusKeys.of("workcell/ho/", "monitor-a").holds
    with open_session(cfg) as session:
        _meet(session, key)
        for boot in boots:
            for seq in range(1, int(each_s / 0.05) + 1):
                payload = holds_payload("ho", "monitor-a", boot, seq, time.time(), ())
                session.put(key, payload, attachment=Signer(KEY_A).sign(key, payload))
                time.sleep(0.05)


def test_a_peer_restarted_within_the_silence_timeout_latches(detector):
    """The attack: monitor-a restarts (a new boot) faster than ``peer_timeout_s``. No silence
    is seen, and the new run knows nothing of the persons its old run had lost or that left its
    view while it was down; with ``restart_interlock = "auto"`` the first version went back to
    RUN. A peer's new boot is a latched ``handover_restarted`` STOP: an operator must look."""
    with _monitor_b(detector) as (port, link):
        _feed_boots(port, ["boot-one"])
        assert link.faults() == ()  # one run, heard on time
        _feed_boots(port, ["boot-two"], each_s=0.3)
        faults = link.faults()
    (fault,) = faults
    assert fault.name == "handover_restarted" and fault.stop and fault.latch
    assert "monitor-a restarted" in fault.reason


def _genuine(port: int, stop: threading.Event) -> None:
    """Monitor-a's own holds messages (``HoldsSender``, as ``HoldsLink`` sends them), 20 Hz."""
    cfg = BusConfig(cell="ho", connect=(f"tcp/127.0.0.1:{port}",), instance="peer-a")
    key = BusKeys.of("workcell/ho/", "monitor-a").holds
    sender = HoldsSender(Signer(KEY_A), key, "ho", "monitor-a", "boot-a")
    with open_session(cfg) as session:
        while not stop.wait(0.05):
            payload, attachment = sender.message(time.time(), ())
            session.put(key, payload, attachment=attachment)


def _flood(port: int, per_s: float, seconds: float, sent: list[int]) -> None:
    """A keyless attacker at ``per_s`` messages a second for ``seconds``: copies of monitor-a's
    newest message with a higher seq and 64 zero bytes as the signature, half of them with a
    seq and a random token in the attachment, and every genuine token it sees copied onto a
    forged payload (the race a copier can try)."""
    cfg = BusConfig(cell="ho", connect=(f"tcp/127.0.0.1:{port}",), instance="attacker")
    key = BusKeys.of("workcell/ho/", "monitor-a").holds
    newest: list = [None]
    with open_session(cfg) as session:
        session.declare_subscriber(key, lambda s: newest.__setitem__(
            0, (s.payload.to_bytes(), s.attachment.to_bytes())))
        assert wait_for(lambda: newest[0] is not None, timeout=20), "no genuine message seen"
        start = time.monotonic()
        n = 0
        while (now := time.monotonic()) < start + seconds:
            if n > (now - start) * per_s:
                time.sleep(0.001)
                continue
            payload, attachment = newest[0]
            body = json.loads(payload)
            body["seq"] += 1 + n % 5
            body["entries"] = []
            forged = json.dumps(body).encode()
            seq = body["seq"].to_bytes(8, "big")
            kind = n % 3
            if kind == 0:
                tail = b""
            elif kind == 1:
                tail = seq + os.urandom(16)
            else:  # the genuine token just revealed, on a payload of the attacker's
                tail = attachment[64:]
            session.put(key, forged, attachment=bytes(64) + tail)
            n += 1
    sent.append(n)


@pytest.mark.slow  # a 3 s flood
def test_a_keyless_flood_on_a_peers_holds_key_leaves_the_genuine_peer_verified(detector):
    """Issue 31: 64-zero-byte "signatures" spent the one budget of 100 checks/s, monitor-a went
    unverified and monitor-b latched ``handover_silent`` after 2.65 s. Forgeries now land on
    monitor-a's cold budget; its genuine messages vouch for each other and are all checked."""
    stop = threading.Event()
    with _monitor_b(detector) as (port, link):
        genuine = threading.Thread(target=_genuine, args=(port, stop), daemon=True)
        genuine.start()
        try:
            assert wait_for(lambda: link.gate.verified["monitor-a"] >= 5, timeout=20), \
                "monitor-a's genuine messages were never verified"
            before = link.gate.verified["monitor-a"]
            sent: list[int] = []
            attacker = threading.Thread(target=_flood, args=(port, 10_000.0, 3.0, sent))
            attacker.start()
            faults = []
            while attacker.is_alive():
                faults += [f for f in link.faults() if f.name == "handover_silent"]
                time.sleep(0.05)
            attacker.join()
            faults += [f for f in link.faults() if f.name == "handover_silent"]
            during = link.gate.verified["monitor-a"] - before
        finally:
            stop.set()
            genuine.join(5.0)
        counts = link.gate.counts()
    refused = counts.get("unchecked", 0) + counts.get("signature", 0)
    print(f"flood: {sent[0]} sent, refused {counts}, genuine verified during it: {during}")
    assert refused >= 5_000, f"the flood never reached the gate: {counts}, sent {sent}"
    assert faults == [], faults[0]
    assert during >= 40, f"only {during} genuine messages verified in 3 s of flood (60 sent)"
