"""Zone set selections over real Zenoh (docs/cases.md): a monitor bus with the selections'
receiver, a second session sending signed (and unsigned) requests, the pipeline deciding."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from monitor.bus.session import BusConfig, BusKeys, SafetyBus, open_session
from monitor.cases.receiver import CaseReceiver, case_key, request_case
from monitor.cases.requests import case_payload
from monitor.cases.sets import plan_of
from monitor.config import demo_cell_path
from monitor.driver import Driver, StepInputs
from monitor.frames import Frame
from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig
from monitor.scene import DemoScene, Figure, draw_figure
from monitor.types import FrameInfo
from monitor.wire.signing import load_private_key, new_key_pair
from monitor.zones import load_cell, parse_cell
from tests.helpers import (
    assert_one_line_error,
    free_port,
    run_here,
    run_monitor,
    wait_for,
)

POLICY = PolicyConfig(clear_time=0.5, restart_interlock="auto")


def _cell():
    data = yaml.safe_load(demo_cell_path().read_text())
    data["zones"] = [
        {"id": "station-a", "kind": "protective", "shape": "box",
         "min_m": [-2.6, -1.6, 0.0], "max_m": [-1.0, 0.4, 2.2]},
        {"id": "station-b", "kind": "protective", "shape": "box",
         "min_m": [1.0, -1.6, 0.0], "max_m": [2.6, 0.4, 2.2]}]
    data.update(sets=[{"id": "A", "zones": ["station-a"]}, {"id": "B", "zones": ["station-b"]}],
                default_set="A", transitions=[["A", "B"], ["B", "A"]], switch_over_s=1.0)
    return parse_cell(data)


def _person_at_b(seq: int, t: float) -> Frame:
    scene = DemoScene()
    img = scene.background()
    img[::7, ::5] += np.uint8(seq % 3)
    feet = scene.camera.project(np.array([[1.8, -0.6, 0.0], [1.8, -0.6, 1.75]]))
    draw_figure(img, Figure((float(feet[0][0]), float(feet[0][1])),
                            float(feet[0][1] - feet[1][1])))
    return Frame(img, FrameInfo("cam0", seq, t, 1280, 720))


class _Publish:
    """The safety sink's job here: every decided command onto the bus."""

    def __init__(self, bus: SafetyBus) -> None:
        self.bus = bus

    def on_step(self, step) -> None:
        self.bus.publish_command(step.result.command)

    def close(self) -> None:
        pass


def test_a_signed_selection_over_zenoh_switches_sets_and_an_unsigned_one_is_refused(
        tmp_path, detector):
    private, _, public = new_key_pair(tmp_path / "robot.key")
    selectors = tmp_path / "selectors"
    selectors.write_text(f"robot {public}\n")
    port = free_port()
    cfg = BusConfig(cell="t", instance="mon-cases", listen=(f"tcp/127.0.0.1:{port}",),
                    selectors_file=str(selectors))
    cell = _cell()
    pipe = Pipeline(detector, "cam0", POLICY, cell)
    commands: list[dict] = []
    with SafetyBus(cfg) as bus, \
            CaseReceiver.for_bus(bus.session, bus.config, pipe.case_plan) as receiver, \
            open_session(BusConfig(cell="t", connect=(f"tcp/127.0.0.1:{port}",),
                                   instance="robot")) as robot:
        robot.declare_subscriber(BusKeys.of("workcell/t/").command,
                                 lambda s: commands.append(json.loads(s.payload.to_bytes())))
        driver = Driver(pipe, [_Publish(bus)])
        key = case_key("workcell/t/")
        assert key == "workcell/t/safety/case"

        def run(seq0: int, n: int, t0: float):
            out = []
            for k in range(n):
                t = round(t0 + k / 10.0, 6)
                out.append(driver.step(_person_at_b(seq0 + k, t), t,
                                       StepInputs(case_events=receiver.poll())).result)
            return out

        assert run(0, 10, 0.0)[-1].command.state == "RUN"  # set A: station B not protected
        signer = load_private_key(private)
        body = case_payload("robot", "B", 1, cell="t")
        answer = request_case(robot, key, body, signer.sign(key, body), timeout=3.0)
        assert answer is not None and answer["accepted"], answer
        switching = run(10, 5, 1.0)
        assert all(r.command.state == "STOP" for r in switching)
        assert switching[0].command.zone_sets == ("A", "B")
        assert wait_for(lambda: any(c.get("zone_sets") == ["A", "B"] for c in commands))

        # unsigned, and the signed one again (replayed): refused with the reason, no event
        unsigned = case_payload("robot", "A", 2, cell="t")
        answer = request_case(robot, key, unsigned, None, timeout=3.0)
        assert answer is not None and not answer["accepted"]
        assert "unsigned" in answer["reason"]
        answer = request_case(robot, key, body, signer.sign(key, body), timeout=3.0)
        assert not answer["accepted"] and "replayed" in answer["reason"]
        assert receiver.poll() == ()
        after = run(15, 2, 1.5)[-1].command
        assert after.zone_sets == ("A", "B")  # still switching over: nothing changed
        assert not {r.fault for r in after.reasons} & {"case_refused"}
        assert receiver.refused == 2 and receiver.accepted == 1


def test_an_unsigned_packet_on_safety_case_neither_stops_nor_latches(tmp_path, detector):
    """Issue 31: one unsigned put on safety/case latched the cell (case_refused). With the
    manual restart interlock (every STOP latches) the cell keeps running through 20 of them."""
    _, _, public = new_key_pair(tmp_path / "robot.key")
    (tmp_path / "selectors").write_text(f"robot {public}\n")
    port = free_port()
    cfg = BusConfig(cell="t", instance="mon-dos", listen=(f"tcp/127.0.0.1:{port}",),
                    selectors_file=str(tmp_path / "selectors"))
    pipe = Pipeline(detector, "cam0", PolicyConfig(clear_time=0.5, restart_interlock="manual"),
                    _cell())
    with SafetyBus(cfg) as bus, \
            CaseReceiver.for_bus(bus.session, bus.config, pipe.case_plan) as receiver, \
            open_session(BusConfig(cell="t", connect=(f"tcp/127.0.0.1:{port}",),
                                   instance="attacker")) as attacker:
        driver = Driver(pipe, [_Publish(bus)])

        def step(k: int):
            t = round(k / 10.0, 6)
            return driver.step(_person_at_b(k, t), t,
                               StepInputs(case_events=receiver.poll())).result.command

        assert [step(k) for k in range(10)][-1].state == "RUN"  # set A: B's person is no hazard
        key = BusKeys.of("workcell/t/").case
        for seq in range(20):
            attacker.put(key, case_payload("robot", "B", 100 + seq, cell="t"))
        assert wait_for(lambda: receiver.refused == 20, timeout=20), \
            f"the unsigned packets did not all arrive ({receiver.refused} of 20)"
        after = [step(k) for k in range(10, 20)]
        assert all(c.state == "RUN" and c.zone_sets == ("A",) for c in after), after[-1]
        assert pipe.state.latched_by is None


@pytest.mark.slow  # two `monitor case select` processes against a bus in this one
def test_cli_zone_sets_and_a_signed_case_select(tmp_path):
    data = yaml.safe_load(demo_cell_path().read_text())
    data["zones"] = [
        {"id": "station-a", "kind": "protective", "shape": "box",
         "min_m": [-2.6, -1.6, 0.0], "max_m": [-1.0, 0.4, 2.2]},
        {"id": "station-b", "kind": "protective", "shape": "box",
         "min_m": [1.0, -1.6, 0.0], "max_m": [2.6, 0.4, 2.2]}]
    cell_file = tmp_path / "cell.yaml"
    cell_file.write_text(yaml.safe_dump(data))
    assert run_here("zones", "set", "add", cell_file, "A", "--zones", "station-a"
                    ).returncode == 0
    assert run_here("zones", "set", "add", cell_file, "B", "--zones", "station-b",
                    "--speed-scale", "0.2").returncode == 0
    bad = run_here("zones", "set", "add", cell_file, "C", "--zones", "nowhere")
    assert_one_line_error(bad, "no zone 'nowhere'")
    listed = run_here("zones", "set", "list", cell_file).stdout
    assert "* A: station-a" in listed and "B: station-b  speed<=0.2" in listed
    assert "id: B" in run_here("zones", "set", "show", cell_file, "B").stdout
    cell = load_cell(cell_file)
    assert cell.spec.default_set == "A"

    private, _, public = new_key_pair(tmp_path / "robot.key")
    new_key_pair(tmp_path / "other.key")
    (tmp_path / "selectors").write_text(f"robot {public}\n")
    port = free_port()
    cfg = BusConfig(cell="t", instance="mon-cli", listen=(f"tcp/127.0.0.1:{port}",),
                    selectors_file=str(tmp_path / "selectors"))
    plan = plan_of(cell.spec)
    with SafetyBus(cfg) as bus, CaseReceiver.for_bus(bus.session, bus.config, plan) as rx:
        common = ("--cell", "t", "--connect", f"tcp/127.0.0.1:{port}", "--selector", "robot")
        ok = run_monitor("case", "select", "B", *common, "--key", private)
        assert ok.returncode == 0, ok.stderr
        assert "verified" in ok.stdout
        forged = run_monitor("case", "select", "A", *common, "--key", tmp_path / "other.key")
        assert forged.returncode == 1 and "signature does not match" in forged.stdout
        events = rx.poll()
    # a refused (forged) selection is answered and counted, never queued: it changes nothing
    assert [type(e).__name__ for e in events] == ["Selection"]
