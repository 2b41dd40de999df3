"""SafetyBus over real Zenoh sessions on tcp/127.0.0.1, and the consumer rule."""

from __future__ import annotations

import json
import logging
import threading
import time

import pytest
import zenoh

from monitor.bus.session import (
    COMMAND_SCHEMA,
    BusConfig,
    BusKeys,
    CommandWatchdog,
    SafetyBus,
    open_session,
    reset_payload,
    zenoh_config,
)
from monitor.errors import ConfigError
from monitor.policy import Command, Latch, Reason, ResetOutcome
from monitor.types import Alert, FrameInfo, Persons, ZoneHit, ZoneReport
from monitor.wire.alerts import AlertLimits
from monitor.wire.resets import request_reset
from monitor.wire.signing import load_private_key, new_key_pair
from tests.helpers import free_port, wait_for
from tests.tls import make_tls

RUN_CMD = Command("RUN", 1.0, (), since=1.0)
SLOW_CMD = Command("SLOW", 0.4, (Reason("warning_zone", "person 0 in zone W1", zone_id="W1",
                                        person=0),), since=2.0)


class Listener:
    """A second session (the 'controller') connected to the monitor over loopback TCP."""

    def __init__(self, port: int, cell: str = "t") -> None:
        self.keys = BusKeys.of(f"workcell/{cell}/")
        self.cfg = BusConfig(cell=cell, connect=(f"tcp/127.0.0.1:{port}",), instance="ctl")
        self.commands: list[dict] = []
        self.alerts: list[tuple[dict, bytes | None]] = []
        self.detections: list[dict] = []
        self.alive: list[tuple[str, bool]] = []
        self.qos: list[tuple] = []

    def _on_command(self, x: zenoh.Sample) -> None:
        self.qos.append((str(x.priority), x.express, str(x.congestion_control)))
        self.commands.append(json.loads(x.payload.to_bytes()))

    def __enter__(self):
        self.session = open_session(self.cfg)
        s = self.session
        s.declare_subscriber(self.keys.command, self._on_command)
        s.declare_subscriber(self.keys.alert, lambda x: self.alerts.append(
            (json.loads(x.payload.to_bytes()),
             x.attachment.to_bytes() if x.attachment else None)))
        s.declare_subscriber(self.keys.detections, lambda x: self.detections.append(
            json.loads(x.payload.to_bytes())))
        s.liveliness().declare_subscriber(self.keys.alive + "/*", lambda x: self.alive.append(
            (str(x.key_expr), x.kind == zenoh.SampleKind.PUT)), history=True)
        return self

    def __exit__(self, *exc):
        self.session.close()

    def status(self) -> dict:
        replies = list(self.session.get(self.keys.status, timeout=3.0))
        assert len(replies) == 1 and replies[0].ok is not None
        return json.loads(replies[0].ok.payload.to_bytes())


@pytest.fixture
def bus_and_listener():
    port = free_port()
    cfg = BusConfig(cell="t", instance="mon1", listen=(f"tcp/127.0.0.1:{port}",),
                    heartbeat_hz=20.0, ttl_ms=200, config_hash="abc123", stall_timeout=0.6)
    with SafetyBus(cfg, alert_limits=AlertLimits(min_interval=10.0)) as bus, \
            Listener(port) as ctl:
        assert wait_for(lambda: all(p.matching_status.matching for p in (
            bus._pub_command, bus._pub_alert, bus._pub_detections)))  # all routes are up
        yield bus, ctl


# --- config ---------------------------------------------------------------------------------


def test_zenoh_config_maps_the_service_settings():
    cfg = BusConfig(mode="client", connect=("tls/router:7447",), tls_root_ca="/etc/ca.pem",
                    tls_cert="/etc/c.pem", tls_key="/etc/c.key", tls_mutual=True, user="monitor",
                    password="pw", block_wait_ms=20, lease_ms=1500)
    z = zenoh_config(cfg)
    assert json.loads(z.get_json("mode")) == "client"
    assert json.loads(z.get_json("connect/endpoints")) == ["tls/router:7447"]
    assert json.loads(z.get_json("scouting/multicast/enabled")) is False
    assert json.loads(z.get_json(
        "transport/link/tx/queue/congestion_control/block/wait_before_close")) == 20000
    assert json.loads(z.get_json("transport/link/tx/lease")) == 1500
    assert json.loads(z.get_json("transport/link/tls/root_ca_certificate")) == "/etc/ca.pem"
    assert json.loads(z.get_json("transport/link/tls/enable_mtls")) is True
    assert json.loads(z.get_json("transport/auth/usrpwd/user")) == "monitor"
    assert BusConfig(cell="c7").key_prefix == "workcell/c7/"
    assert BusConfig(prefix="plant/a").key_prefix == "plant/a/"


@pytest.mark.parametrize("kwargs", [
    {"mode": "broker"}, {"cell": "a/b"}, {"heartbeat_hz": 0}, {"ttl_ms": 50},
    {"user": "u"}, {"tls_cert": "c.pem"},
])
def test_bad_bus_config_is_a_config_error(kwargs):
    with pytest.raises(ConfigError):
        BusConfig(**kwargs)


def test_open_session_on_a_taken_port_is_a_config_error():
    port = free_port()
    with open_session(BusConfig(listen=(f"tcp/127.0.0.1:{port}",))), \
            pytest.raises(ConfigError, match="cannot open"):
        open_session(BusConfig(listen=(f"tcp/127.0.0.1:{port}",))).close()


# --- publishing ------------------------------------------------------------------------------


def test_a_command_decided_before_a_freeze_goes_out_as_a_stalled_stop(bus_and_listener):
    """The process froze between the decision and the publishing (SIGSTOP, a paused VM): the
    RUN decided before says nothing about the cell now. A STOP "stalled" goes out instead, and
    the heartbeat repeats that STOP, never the RUN."""
    bus, ctl = bus_and_listener
    assert bus.publish_command(SLOW_CMD, decided_at=time.monotonic()) is not None
    assert bus.publish_command(RUN_CMD, decided_at=time.monotonic() - 0.7) is not None
    stalled = wait_for(lambda: [c for c in list(ctl.commands)
                                if {r["code"] for r in c["reasons"]} == {"stalled"}])
    assert stalled[0]["state"] == "STOP" and not stalled[0]["heartbeat"]
    assert "decided 0.7" in stalled[0]["reasons"][0]["message"]
    time.sleep(0.15)  # three heartbeats at 20 Hz
    assert not any(c["state"] == "RUN" for c in list(ctl.commands))
    # a fresh decision (age within stall_timeout = 0.6 s) goes out as decided
    assert bus.publish_command(RUN_CMD, decided_at=time.monotonic() - 0.5) is not None
    assert wait_for(lambda: any(c["state"] == "RUN" for c in list(ctl.commands)))


def test_commands_carry_the_envelope_and_go_out_on_change(bus_and_listener):
    bus, ctl = bus_and_listener
    assert bus.publish_command(RUN_CMD) is not None
    assert bus.publish_command(RUN_CMD) is None  # unchanged: left to the heartbeat
    near = Command("SLOW", 0.4, (Reason("separation_margin", "1.10 m", distance_m=1.1),))
    nearer = Command("SLOW", 0.4, (Reason("separation_margin", "1.05 m", distance_m=1.05),))
    assert bus.publish_command(near) is not None
    assert bus.publish_command(nearer) is None  # same cause, new distance: heartbeat carries it
    assert bus.publish_command(SLOW_CMD) is not None
    assert wait_for(lambda: any(c["state"] == "SLOW" and c["reasons"][0].get("zone_id")
                                for c in ctl.commands))
    first = next(c for c in ctl.commands if not c["heartbeat"])
    for field in ("schema", "seq", "mono", "wall", "ttl_ms", "config_hash", "instance", "boot"):
        assert field in first
    assert first["schema"] == COMMAND_SCHEMA and first["config_hash"] == "abc123"
    assert first["instance"] == "mon1" and first["ttl_ms"] == 200
    slow = next(c for c in ctl.commands if c["state"] == "SLOW" and c["speed_scale"] == 0.4
                and c["reasons"][0]["code"] == "warning_zone")
    assert slow["speed_scale"] == 0.4 and slow["reasons"][0]["zone_id"] == "W1"
    seqs = [c["seq"] for c in ctl.commands]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert set(ctl.qos) == {(str(zenoh.Priority.REAL_TIME), True,
                             str(zenoh.CongestionControl.BLOCK))}


def test_heartbeat_repeats_the_latest_command_and_stops_for_a_stalled_pipeline(bus_and_listener):
    bus, ctl = bus_and_listener
    records: list[logging.LogRecord] = []
    handler = logging.Handler()
    handler.emit = records.append
    logging.getLogger("monitor.bus.session").addHandler(handler)
    bus.publish_command(RUN_CMD)
    assert wait_for(lambda: sum(c["heartbeat"] and c["state"] == "RUN"
                                for c in ctl.commands) >= 3)
    # no publish_command for stall_timeout: the heartbeat must not keep saying RUN
    assert wait_for(lambda: any(c["state"] == "STOP" and c["reasons"][0]["code"] == "stalled"
                                for c in ctl.commands))
    last_run = max(c["mono"] for c in ctl.commands if c["state"] == "RUN")
    first_stall = min(c["mono"] for c in ctl.commands if c["state"] == "STOP")
    assert first_stall - last_run <= 0.6 + 2 / 20 + 0.1
    # the STOP a consumer acts on is in the monitor's own log too, once (not every heartbeat)
    logging.getLogger("monitor.bus.session").removeHandler(handler)
    said = [r.getMessage() for r in records if "STOP stalled" in r.getMessage()]
    assert len(said) == 1 and "bus.stall_timeout 0.6 s" in said[0]


def test_heartbeats_of_a_latched_command_keep_its_latch_and_reset_possibility(bus_and_listener):
    """A PLC or console reading between two changes must see what the last command said: the
    heartbeat repeats the whole command (not only state and reasons), never the reset answer."""
    bus, ctl = bus_and_listener
    latched = Command("STOP", 0.0, (Reason("latched", "waiting for a reset"),), since=1.0,
                      latched=True, latched_by=Latch("protective_zone", "person 1 in P", 0.5,
                                                     "P", 1, "n-1"),
                      reset_possible=True, reset_possible_since=0.9, clear_for_s=1.2,
                      reset=ResetOutcome("anna", False, "refused: too early", "r-9"))
    bus.publish_command(latched)
    beats = wait_for(lambda: len(b := [c for c in list(ctl.commands) if c["heartbeat"]
                                       and c["state"] == "STOP" and c["latched"]]) >= 3 and b)
    assert beats and len(beats) >= 3
    for beat in beats:
        assert beat["latched"] and beat["reset_possible"] is True
        assert beat["latched_by"]["nonce"] == "n-1" and beat["latched_by"]["zone_id"] == "P"
        assert "reset" not in beat  # the outcome went out once, with the change


def test_close_sends_stop_shutdown_and_drops_the_liveliness_token():
    port = free_port()
    cfg = BusConfig(cell="t", instance="mon2", listen=(f"tcp/127.0.0.1:{port}",))
    with Listener(port) as ctl:
        with SafetyBus(cfg) as bus:
            assert wait_for(lambda: ("workcell/t/safety/alive/mon2", True) in ctl.alive)
            bus.publish_command(RUN_CMD)
            assert wait_for(lambda: bool(ctl.commands))
        assert wait_for(lambda: ("workcell/t/safety/alive/mon2", False) in ctl.alive)
        assert ctl.commands[-1]["state"] == "STOP"
        assert ctl.commands[-1]["reasons"][0]["code"] == "shutdown"


def test_alerts_are_rate_limited_per_kind_with_repeat_count_and_snapshot(bus_and_listener):
    bus, ctl = bus_and_listener
    jpeg = b"\xff\xd8\xff\xe0fakejpeg\xff\xd9"
    a = Alert("scene_change", "warning", "cover fell", "cam0", 5.0, snapshot_jpeg=jpeg)
    assert bus.publish_alert(a)
    assert not bus.publish_alert(a)  # same kind within min_interval: held back, counted
    assert not bus.publish_alert(a)
    assert bus.publish_alert(Alert("camera_defocused", "info", "blurry", "cam1", 5.1))
    assert wait_for(lambda: len(ctl.alerts) == 2)
    body, attachment = ctl.alerts[0]
    assert body["kind"] == "scene_change" and body["repeat"] == 0 and attachment == jpeg
    assert body["snapshot"]["bytes"] == len(jpeg)
    assert ctl.alerts[1][1] is None
    assert bus.status()["alerts_held"] == {"scene_change": 2}
    bus._limiter.limits = AlertLimits(min_interval=0.0)
    assert bus.publish_alert(a)
    assert wait_for(lambda: len(ctl.alerts) == 3)
    assert ctl.alerts[2][0]["repeat"] == 2


def test_detections_carry_boxes_and_hits(bus_and_listener):
    bus, ctl = bus_and_listener
    persons = Persons([[10, 20, 110, 320]], [0.9], FrameInfo("cam0", 42, 3.5, 640, 480))
    report = ZoneReport(hits=(ZoneHit("W1", "warning", 0, 0.5, 1.3),))
    bus.publish_detections(persons, report, fps=12.5)
    assert wait_for(lambda: bool(ctl.detections))
    d = ctl.detections[0]
    assert d["frame"]["seq"] == 42 and d["boxes_px"] == [[10.0, 20.0, 110.0, 320.0]]
    assert d["hits"][0]["zone_id"] == "W1" and d["fps"] == 12.5


def test_status_queryable_answers_with_state_and_counters(bus_and_listener):
    bus, ctl = bus_and_listener
    bus.publish_command(Command("STOP", 0.0, (), reset=ResetOutcome("op1", True, "reset accepted")))
    bus.update_status(fps=14.2, cameras={"cam0": "ok"})
    st = ctl.status()
    assert st["state"] == "STOP" and st["config_hash"] == "abc123" and st["fps"] == 14.2
    assert st["uptime_s"] > 0 and st["last_reset"]["operator"] == "op1"
    assert st["puts"]["workcell/t/safety/command"] >= 1
    # nobody listens to detections except... nobody: the put is counted as unmatched
    bus.publish_detections(None, None)
    ctl.session.close()
    # Zenoh tells the publisher asynchronously that its last subscriber left: wait for it
    # (publishing at once raced with that and counted the put as matched, 1 run in 3)
    assert wait_for(lambda: not bus._pub_detections.matching_status.matching)
    bus.publish_detections(None, None)  # the listener is gone now
    assert bus.status()["puts_unmatched"].get("workcell/t/safety/detections", 0) >= 1


def test_unsigned_resets_are_refused_without_operators_and_invalid_ones_counted(
        bus_and_listener):
    bus, ctl = bus_and_listener
    ctl.session.put(ctl.keys.reset, reset_payload("anna", "r1", "checked the cell"))
    ctl.session.put(ctl.keys.reset, b'{"note": "no operator"}')
    ctl.session.put(ctl.keys.reset, b"garbage")
    assert wait_for(lambda: bus.status()["resets_refused"] == 3)
    st = bus.status()
    assert st["resets_invalid"] == 2  # the two without an operator
    assert st["last_reset"]["accepted"] is False
    assert bus.poll_resets() == []  # the policy never sees them
    assert wait_for(lambda: any(a["kind"] == "reset_refused" for a, _ in ctl.alerts))
    first = next(a for a, _ in ctl.alerts if a["kind"] == "reset_refused")
    assert "anna" in first["message"] and "no operators configured" in first["message"]


def test_command_puts_from_two_threads_stay_in_seq_order(bus_and_listener):
    bus, ctl = bus_and_listener

    def flap(n):
        for i in range(n):
            bus.publish_command(RUN_CMD if i % 2 else SLOW_CMD)

    threads = [threading.Thread(target=flap, args=(100,)) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    sent = bus._seq[bus.keys.command]
    assert wait_for(lambda: bool(ctl.commands) and ctl.commands[-1]["seq"] > sent)
    seqs = [c["seq"] for c in ctl.commands]
    assert seqs == sorted(seqs)
    last_change = [c for c in ctl.commands if not c["heartbeat"]][-1]
    assert last_change["state"] == bus.status()["state"]  # the wire ends on the newest command


# --- the consumer rule (pure) ---------------------------------------------------------------


def cmd_payload(seq: int, state: str = "RUN", boot: str = "b1", ttl: int = 300,
                instance: str = "mon1") -> bytes:
    return json.dumps({"schema": COMMAND_SCHEMA, "seq": seq, "boot": boot, "state": state,
                       "speed_scale": 1.0 if state == "RUN" else 0.0, "ttl_ms": ttl,
                       "instance": instance, "reasons": []}).encode()


def test_watchdog_rule_table():
    dog = CommandWatchdog()
    assert dog.verdict(0.0).code == "no_command"
    dog.on_liveliness("workcell/t/safety/alive/mon1", True)
    assert dog.on_command(cmd_payload(1), 1.0) is None
    assert dog.verdict(1.0).state == "RUN"
    assert dog.verdict(1.299).state == "RUN"  # just under ttl old
    assert dog.verdict(1.301).code == "ttl"  # older than ttl: STOP
    assert dog.on_command(cmd_payload(2), 1.4) is None
    assert dog.on_command(cmd_payload(2), 1.5) == "seq"  # repeated seq
    assert dog.verdict(1.5).code == "sequence"
    assert dog.on_command(cmd_payload(1), 1.5) == "seq"  # backwards
    assert dog.on_command(cmd_payload(3), 1.6) is None  # newer one clears the error
    assert dog.verdict(1.6).state == "RUN"
    dog.on_liveliness("workcell/t/safety/alive/mon1", False)
    v = dog.verdict(1.61)
    assert v.state == "STOP" and v.code == "liveliness" and "vanished" in v.reason
    dog.on_liveliness("workcell/t/safety/alive/mon1", True)
    assert dog.on_command(cmd_payload(1, boot="b2"), 1.7) is None  # monitor restarted
    assert dog.verdict(1.7).state == "RUN"
    assert dog.on_command(b"{bad", 1.8) == "invalid"
    assert dog.on_command(cmd_payload(5, state="GO"), 1.8) == "invalid"


def test_watchdog_caps_ttl_and_filters_instances():
    dog = CommandWatchdog(max_ttl_ms=100, instance="mon1", require_liveliness=False)
    assert dog.on_command(cmd_payload(1, ttl=5000), 0.0) is None
    assert dog.verdict(0.1).state == "RUN" and dog.verdict(0.11).code == "ttl"
    assert dog.on_command(cmd_payload(9, instance="rogue"), 0.2) == "other_instance"


# --- TLS, user/password and access control (deploy/zenoh/router-secure.json5) -----------------




DEPLOY = __import__("pathlib").Path(__file__).resolve().parents[1] / "deploy" / "zenoh"


def test_secure_router_only_monitor_publishes_commands_only_operators_reset(tmp_path):
    pytest.importorskip("cryptography")
    tls = make_tls(tmp_path)
    users = tmp_path / "users.txt"
    users.write_text("monitor:m-pw\noperator1:o-pw\nviewer:v-pw\nrogue:r-pw\n")
    port = free_port()
    conf = zenoh.Config.from_file(str(DEPLOY / "router-secure.json5"))
    for key, value in {
        "listen/endpoints": [f"tls/127.0.0.1:{port}"],
        "transport/link/tls/root_ca_certificate": str(tls["ca"]),
        "transport/link/tls/listen_certificate": str(tls["cert"]),
        "transport/link/tls/listen_private_key": str(tls["key"]),
        "transport/auth/usrpwd/dictionary_file": str(users),
    }.items():
        conf.insert_json5(key, json.dumps(value))

    def client(user, password, **kw):
        return BusConfig(cell="sec", mode="client", instance=user,
                         zenoh_config_file=str(DEPLOY / "client-secure.json5"),
                         connect=(f"tls/localhost:{port}",), tls_root_ca=str(tls["ca"]),
                         user=user, password=password, **kw)

    keys = BusKeys.of("workcell/sec/")
    ops = {name: new_key_pair(tmp_path / f"{name}.key")[2] for name in ("operator1", "rogue")}
    (tmp_path / "operators").write_text(f"operator1 {ops['operator1']}\n")
    seen: list[dict] = []
    with zenoh.open(conf), SafetyBus(client(
            "monitor", "m-pw", operators_file=str(tmp_path / "operators"))) as bus, \
            open_session(client("viewer", "v-pw")) as viewer, \
            open_session(client("rogue", "r-pw")) as rogue, \
            open_session(client("operator1", "o-pw")) as operator:
        viewer.declare_subscriber(keys.command, lambda s: seen.append(
            json.loads(s.payload.to_bytes())))
        assert wait_for(lambda: bus._pub_command.matching_status.matching)
        bus.publish_command(RUN_CMD)
        assert wait_for(lambda: any(c.get("instance") == "monitor" for c in seen))
        # a rogue client cannot command the robot nor release a latched STOP
        rogue.put(keys.command, json.dumps({"state": "RUN", "instance": "rogue"}))
        def signed(name):
            payload = reset_payload(name, cell="sec", boot=bus.boot, latch="1-0123456789abcdef")
            return payload, load_private_key(tmp_path / f"{name}.key").sign(keys.reset, payload)

        rogue.put(keys.reset, signed("rogue")[0], attachment=signed("rogue")[1])
        viewer.put(keys.reset, reset_payload("viewer"))
        answer = request_reset(viewer, keys.reset, *signed("operator1"), timeout=1.0)
        assert answer is None  # the ACL drops a viewer's reset query (second layer)
        answers = []
        asker = threading.Thread(target=lambda: answers.append(request_reset(
            operator, keys.reset, *signed("operator1"), timeout=5.0)))
        asker.start()
        got = []
        assert wait_for(lambda: bool(got.extend(bus.poll_resets()) or got))
        time.sleep(0.3)  # give the denied messages time to (not) arrive
        got += bus.poll_resets()
        assert [r.operator for r in got] == ["operator1"]
        # the policy's outcome is the answer to the operator's query
        bus.publish_command(Command("STOP", 0.0, (), 1.0, reset=ResetOutcome(
            "operator1", False, "refused: person 0 in zone P1", got[0].request_id)))
        asker.join(5.0)
        assert answers[0]["accepted"] is False and "person 0" in answers[0]["reason"]
        assert not any(c.get("instance") == "rogue" for c in seen)
        # and everyone may read the status
        replies = list(viewer.get(keys.status, timeout=3.0))
        assert json.loads(replies[0].ok.payload.to_bytes())["instance"] == "monitor"
    # wrong password: the router refuses the session
    with zenoh.open(conf), pytest.raises(ConfigError):
        open_session(client("monitor", "wrong")).close()


def test_alert_limiter_per_kind_with_critical_interval():
    from monitor.wire.alerts import AlertLimiter, alert_from_dict, alert_to_dict, reset_alert

    lim = AlertLimiter(AlertLimits(min_interval=5.0, critical_min_interval=1.0))
    warn = Alert("camera_frozen", "warning", "m", "cam0", 0.0)
    crit = Alert("camera_lost", "critical", "m", "cam0", 0.0)
    assert [lim.admit(warn, t) for t in (0.0, 1.0, 4.9, 5.0)] == [0, None, None, 2]
    assert [lim.admit(crit, t) for t in (0.0, 0.5, 1.0)] == [0, None, 1]
    assert lim.held() == {}
    with pytest.raises(ValueError):
        alert_to_dict(Alert("x", "fatal", "m", "s", 0.0))
    body = alert_to_dict(Alert("x", "info", "m", "s", 1.0, snapshot_jpeg=b"jpg"), repeat=3)
    back = alert_from_dict(json.loads(json.dumps(body)), b"jpg")
    assert back.snapshot_jpeg == b"jpg" and back.details["repeat"] == 3
    refused = reset_alert(ResetOutcome("anna", False, "refused: person 0 in zone Z1"), "m1", 2.0)
    assert refused.kind == "reset_refused" and refused.severity == "warning"
    assert "anna" in refused.message


def _frozen_subscriber(port: int) -> None:
    with open_session(BusConfig(cell="blk", connect=(f"tcp/127.0.0.1:{port}",))) as s:
        s.declare_subscriber(BusKeys.of("workcell/blk/").command, lambda x: None)
        time.sleep(60)


def test_a_frozen_subscriber_stalls_command_puts_only_for_the_bounded_wait():
    """BLOCK congestion control with wait_before_close = block_wait_ms: a subscriber that stops
    reading (SIGSTOP) costs at most about that wait per put (Zenoh's default would stall the
    monitor for 5 s)."""
    import multiprocessing
    import os
    import signal

    port = free_port()
    cfg = BusConfig(cell="blk", instance="m", listen=(f"tcp/127.0.0.1:{port}",),
                    block_wait_ms=50)
    proc = multiprocessing.get_context("spawn").Process(target=_frozen_subscriber, args=(port,),
                                                        daemon=True)
    with SafetyBus(cfg) as bus:
        proc.start()
        try:
            assert wait_for(lambda: bus._pub_command.matching_status.matching)
            os.kill(proc.pid, signal.SIGSTOP)
            big = [Command(s, v, (Reason("test", c * 300),)) for s, v, c in
                   (("RUN", 1.0, "a"), ("SLOW", 0.5, "b"))]
            durations = [0.0]
            # until the link congests (a quiet host: within ~0.2 s, ~10x less data than 2 s of
            # puts), then 100 puts more; a loaded host puts more slowly: 30 s of ceiling
            end, congested = time.monotonic() + 30.0, None
            while time.monotonic() < end and (congested is None
                                              or len(durations) < congested + 100):
                t = time.perf_counter()
                bus.publish_command(big[len(durations) % 2])
                durations.append(time.perf_counter() - t)
                if congested is None and durations[-1] >= 0.04:
                    congested = len(durations)
            assert max(durations) >= 0.04, "the link never congested: test proves nothing"
            assert max(durations) < 1.0, f"a put blocked {max(durations):.2f} s"
            assert bus.status()["put_errors"] == {}
        finally:
            os.kill(proc.pid, signal.SIGKILL)
            proc.join(5)
