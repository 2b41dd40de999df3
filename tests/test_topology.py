"""The plant topology of docs/scaling.md, for real: a line router and a cell router started with
the shipped secure configs (deploy/zenoh/router-line.json5, router-cell.json5) as `monitor
router` processes, linked over TLS with user/password, the cell's monitor on the cell router and
a robot controller's consumer on the line router."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from monitor.bus.session import BusConfig, BusKeys, SafetyBus, open_session
from monitor.policy import Command, Latch
from monitor.wire.consumer import CommandWatchdog
from monitor.wire.resets import LatchNonces, reset_payload
from monitor.wire.signing import load_private_key, load_public_key, new_key_pair
from tests.helpers import free_port, wait_for
from tests.tls import make_tls

ZENOH = Path(__file__).resolve().parents[1] / "deploy" / "zenoh"
USERS = {  # one dictionary for both routers here; on site each router has its own
    "router-cell1": "rc1-pw", "monitor": "m-pw", "operator1": "o-pw", "viewer": "v-pw",
    "monitor-cell2": "mc2-pw", "operators-cell1": "oc1-pw", "monitor-cell1": "mc1-pw",
}


def _site_config(tmp: Path, name: str, tls: dict) -> Path:
    """The shipped file with its /etc/workcell/ files replaced by this test's."""
    text = (ZENOH / name).read_text()
    for etc, mine in {"/etc/workcell/tls/ca.pem": tls["ca"],
                      "/etc/workcell/tls/router.pem": tls["cert"],
                      "/etc/workcell/tls/router.key": tls["key"],
                      "/etc/workcell/zenoh-users.txt": tmp / "users.txt"}.items():
        assert etc in text, f"{name} no longer names {etc}"
        text = text.replace(etc, str(mine))
    path = tmp / name
    path.write_text(text)
    zenoh.Config.from_file(str(path))
    return path


def _router(config: Path, port: int, *extra: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "monitor", "router", "--zenoh-config",
                             str(config), "--listen", f"tls/127.0.0.1:{port}", *extra],
                            stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    assert "listening" in line, line + proc.stderr.read()
    return proc


@pytest.mark.slow
def test_line_and_cell_routers_linked_carry_signed_commands_and_keep_resets_at_the_cell(
        tmp_path):
    tls = make_tls(tmp_path)
    (tmp_path / "users.txt").write_text("".join(f"{u}:{p}\n" for u, p in USERS.items()))
    (tmp_path / "router-cell1.password").write_text(USERS["router-cell1"] + "\n")
    line_port, cell_port = free_port(), free_port()
    line_conf = _site_config(tmp_path, "router-line.json5", tls)
    cell_conf = _site_config(tmp_path, "router-cell.json5", tls)
    signing_key, _, _ = new_key_pair(tmp_path / "monitor.key")
    operator_key, _, operator_public = new_key_pair(tmp_path / "operator1.key")
    (tmp_path / "operators").write_text(f"operator1 {operator_public}\n")

    def client(user: str, port: int, **kw) -> BusConfig:
        return BusConfig(cell="cell1", mode="client", instance=user,
                         zenoh_config_file=str(ZENOH / "client-secure.json5"),
                         connect=(f"tls/localhost:{port}",), tls_root_ca=str(tls["ca"]),
                         user=user, password=USERS[user], **kw)

    keys = BusKeys.of("workcell/cell1/")
    routers = []
    try:
        # the line router keeps dialling its (absent) plant uplink: it must serve anyway
        routers.append(_router(line_conf, line_port))
        routers.append(_router(cell_conf, cell_port, "--connect", f"tls/localhost:{line_port}",
                               "--user", "router-cell1", "--password-file",
                               str(tmp_path / "router-cell1.password")))
        dog = CommandWatchdog(public_keys=[load_public_key(str(signing_key) + ".pub")],
                              cell="cell1")
        seen: list[dict] = []

        def on_command(sample: zenoh.Sample) -> None:
            payload = sample.payload.to_bytes()
            seen.append(json.loads(payload))
            sig = sample.attachment.to_bytes() if sample.attachment is not None else None
            dog.on_command(payload, time.monotonic(), sig, wall_now=time.time())

        with open_session(client("viewer", line_port)) as controller, \
                SafetyBus(client("monitor", cell_port, signing_key=str(signing_key),
                                 operators_file=str(tmp_path / "operators"))) as bus, \
                open_session(client("monitor-cell2", line_port)) as other_cell, \
                open_session(client("operators-cell1", line_port)) as line_panel, \
                open_session(client("operator1", cell_port)) as cell_panel:
            controller.declare_subscriber(keys.command, on_command)
            controller.liveliness().declare_subscriber(
                keys.alive + "/*", lambda s: dog.on_liveliness(
                    str(s.key_expr), s.kind == zenoh.SampleKind.PUT), history=True)
            # the monitor's command crosses cell router -> link -> line router -> controller
            assert wait_for(lambda: bus._pub_command.matching_status.matching)
            bus.publish_command(Command("RUN", 1.0, ()))
            assert wait_for(lambda: dog.verdict(time.monotonic()).state == "RUN",
                            what=lambda: dog.verdict(time.monotonic()))
            assert dog.live_instances(time.monotonic()) == ["monitor"]
            # another cell's monitor cannot write under cell1's keys at the line router
            other_cell.put(keys.command, json.dumps({"state": "RUN", "instance": "c2"}))
            # everyone may read the status, across the link
            replies = list(controller.get(keys.status, timeout=3.0))
            assert json.loads(replies[0].ok.payload.to_bytes())["instance"] == "monitor"

            latch = LatchNonces(bus.boot)(1)
            bus.publish_command(Command("STOP", 0.0, (), 1.0, latched=True, latched_by=Latch(
                "protective_zone", "person 0 in P1", 1.0, nonce=latch)))

            def signed() -> tuple[bytes, bytes]:
                payload = reset_payload("operator1", cell="cell1", boot=bus.boot, latch=latch)
                return payload, load_private_key(operator_key).sign(keys.reset, payload)

            # a correctly signed reset from the line network never reaches the monitor: the
            # cell router takes resets only from panels at the cell
            payload, signature = signed()
            line_panel.put(keys.reset, payload, attachment=signature)
            time.sleep(1.0)
            assert bus.poll_resets() == []
            payload, signature = signed()
            cell_panel.put(keys.reset, payload, attachment=signature)
            got = wait_for(bus.poll_resets)
            assert [r.operator for r in got] == ["operator1"]
            assert not any(c.get("instance") == "c2" for c in seen)
            assert dog.verdict(time.monotonic()).state == "STOP"
    finally:
        for proc in routers:
            proc.terminate()
        for proc in routers:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)


@pytest.mark.slow
@pytest.mark.parametrize("config", ["router-cell.json5", "router-secure.json5"])
def test_router_acl_gives_each_role_the_rights_of_the_cells_only_monitor(tmp_path, config):
    """A cell with roles through the shipped router ACL: the monitor user's role keys (command,
    token, status, reset and mute queryables) work; a read-only user can neither command nor
    hold for a role, nor send an operator's correctly signed reset or mute; the cell router's
    monitor user cannot command another cell."""
    from monitor.cases.mute_requests import mute_payload
    from monitor.wire.cell_consumer import CellWatchdog

    tls = make_tls(tmp_path)
    users = {**USERS, "rogue": "r-pw"}
    (tmp_path / "users.txt").write_text("".join(f"{u}:{p}\n" for u, p in users.items()))
    port = free_port()
    conf = _site_config(tmp_path, config, tls)
    signing_key, _, _ = new_key_pair(tmp_path / "monitor-a.key")
    operator_key, _, operator_public = new_key_pair(tmp_path / "operator1.key")
    (tmp_path / "operators").write_text(f"operator1 {operator_public}\n")

    def client(user: str, **kw) -> BusConfig:
        return BusConfig(cell="cell1", mode="client", instance=kw.pop("instance", user),
                         zenoh_config_file=str(ZENOH / "client-secure.json5"),
                         connect=(f"tls/localhost:{port}",), tls_root_ca=str(tls["ca"]),
                         user=user, password=users[user], **kw)

    keys = BusKeys.of("workcell/cell1/", "monitor-a")
    other_cell = BusKeys.of("workcell/cell2/", "monitor-a")
    dog = CellWatchdog({"monitor-a": (load_public_key(str(signing_key) + ".pub"),)},
                       "workcell/cell1/", cell="cell1")
    seen: list[tuple[str, dict]] = []

    def on_sample(sample: zenoh.Sample) -> None:
        payload, key = sample.payload.to_bytes(), str(sample.key_expr)
        seen.append((key, json.loads(payload)))
        if key.endswith("/command"):
            sig = sample.attachment.to_bytes() if sample.attachment is not None else None
            dog.on_command(payload, time.monotonic(), sig, wall_now=time.time(), key_expr=key)

    router = _router(conf, port)
    try:
        with open_session(client("viewer")) as controller, \
                SafetyBus(client("monitor", instance="mon-a", role="monitor-a",
                                 signing_key=str(signing_key),
                                 operators_file=str(tmp_path / "operators"))) as bus, \
                open_session(client("rogue")) as rogue, \
                open_session(client("operator1")) as panel:
            controller.declare_subscriber("workcell/**", on_sample)
            controller.liveliness().declare_subscriber(
                "workcell/cell1/safety/alive/**", lambda s: dog.on_liveliness(
                    str(s.key_expr), s.kind == zenoh.SampleKind.PUT), history=True)
            # the role's command and token reach the consumer through the router
            assert wait_for(lambda: bus._pub_command.matching_status.matching)
            bus.publish_command(Command("RUN", 1.0, ()))
            assert wait_for(lambda: dog.verdict(time.monotonic()).state == "RUN",
                            what=lambda: dog.verdict(time.monotonic()))
            # everyone may read the role's status
            replies = list(controller.get(keys.status, timeout=3.0))
            assert json.loads(replies[0].ok.payload.to_bytes())["role"] == "monitor-a"

            # a read-only user cannot command or hold for the role, nor release or mute with an
            # operator's correctly signed request
            for key in (keys.command, keys.holds):
                rogue.put(key, json.dumps({"state": "RUN", "instance": "rogue"}))
            latch = LatchNonces(bus.boot)(1)
            bus.publish_command(Command("STOP", 0.0, (), 1.0, latched=True, latched_by=Latch(
                "protective_zone", "person 0 in P1", 1.0, nonce=latch)))
            reset = reset_payload("operator1", cell="cell1", boot=bus.boot, latch=latch)
            reset_sig = load_private_key(operator_key).sign(keys.reset, reset)
            mute = mute_payload("operator1", "P1", 30.0, cell="cell1", boot=bus.boot)
            mute_sig = load_private_key(operator_key).sign(keys.mute, mute)
            rogue.put(keys.reset, reset, attachment=reset_sig)
            rogue.get(keys.reset, payload=reset, attachment=reset_sig, timeout=1.0)
            rogue.get(keys.mute, payload=mute, attachment=mute_sig, timeout=1.0)
            if config == "router-cell.json5":  # this router serves cell1 only
                bus.session.put(other_cell.command, json.dumps({"instance": "mon-a-cell2"}))
            time.sleep(1.0)
            assert bus.poll_resets() == [] and bus.poll_mutes() == ()
            assert not any(body.get("instance") in ("rogue", "mon-a-cell2")
                           for _, body in seen), seen
            # the cell's operator may: the same requests reach the role's monitor
            panel.get(keys.mute, payload=mute, attachment=mute_sig, timeout=1.0)
            assert [m.operator for m in wait_for(bus.poll_mutes)] == ["operator1"]
            panel.put(keys.reset, reset, attachment=reset_sig)
            assert [r.operator for r in wait_for(bus.poll_resets)] == ["operator1"]
    finally:
        router.terminate()
        try:
            router.wait(10)
        except subprocess.TimeoutExpired:
            router.kill()
            router.wait(5)
