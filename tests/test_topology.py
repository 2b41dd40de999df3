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

from monitor.bus import BusConfig, BusKeys, SafetyBus, open_session
from monitor.consumer import CommandWatchdog
from monitor.policy import Command, Latch
from monitor.resets import LatchNonces, reset_payload
from monitor.signing import load_private_key, load_public_key, new_key_pair
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
            assert wait_for(lambda: bus._pub_command.matching_status.matching, timeout=10)
            bus.publish_command(Command("RUN", 1.0, ()))
            assert wait_for(lambda: dog.verdict(time.monotonic()).state == "RUN", timeout=5), \
                dog.verdict(time.monotonic())
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
            got = wait_for(bus.poll_resets, timeout=5)
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
