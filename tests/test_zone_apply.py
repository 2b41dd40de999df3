"""A changed zone file reaches the running service only through an operator's signed apply
(monitor/cases/zone_apply.py, monitor/service/zone_swap.py): a `monitor run` process watching a
person who stands in the warning area; a new protective zone around them gives STOP after the signed
apply and not before, every command then names the new zone set; an unsigned apply, one by an
unknown operator, one whose file changed after signing and one of an invalid file are refused with a
one-line reason and the old zones stay in force."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import pytest

from monitor.cases.zone_apply import apply_payload, request_apply
from monitor.config import demo_cell_path
from monitor.scene import DemoScene, write_video
from monitor.wire.signing import load_private_key, new_key_pair
from monitor.zones import load_cell
from monitor.zones.files import draft_path
from tests.helpers import run_monitor
from tests.processes import Service, codes

# where the person stands: in cam0-warning (SLOW), outside every protective zone
STAND = (-2.6, -0.3)
NEW_ZONE = """
  - id: aisle-stop
    name: Aisle by the door (STOP)
    kind: protective
    shape: polygon
    camera: cam0
    anchor: bottom-centre
    points_px: [[150.0, 380.0], [420.0, 380.0], [420.0, 640.0], [150.0, 640.0]]
"""
BOWTIE = NEW_ZONE.replace("[[150.0, 380.0], [420.0, 380.0], [420.0, 640.0], [150.0, 640.0]]",
                          "[[150.0, 380.0], [420.0, 640.0], [420.0, 380.0], [150.0, 640.0]]")


@pytest.fixture(scope="module")
def service(tmp_path_factory, synthetic_model):
    tmp = tmp_path_factory.mktemp("zone-apply")
    video = tmp / "standing.mp4"
    scene = DemoScene(fps=10.0, duration_s=2.0, path=((0.0, *STAND), (9.0, *STAND)))
    write_video(video, scene.frames(), scene.fps)
    cell = tmp / "cell.yaml"
    shutil.copy(demo_cell_path(), cell)
    # frame_timeout 1 s: at a load of 8 the default 0.5 s latched a stall STOP again and again
    # (this test is about zone swaps, not frame age: tests/test_stall.py)
    svc = Service(tmp, synthetic_model, str(video),
                  f'[zones]\nfile = "{cell}"\n[policy]\nframe_timeout = 1.0\n',
                  camera_lines="loop = true\nrealtime = true\n")
    with svc:
        alerts: list[dict] = []
        svc.session.declare_subscriber(svc.keys.alert, lambda s: alerts.append(
            json.loads(s.payload.to_bytes())))
        svc.reach(0, lambda c: c["state"] == "SLOW", 60, "SLOW: the person in the warning "
                  "area")
        yield svc, tmp, cell, alerts


def _ask(svc: Service, payload: bytes, signature: bytes | None) -> dict:
    answer = request_apply(svc.session, svc.keys.zones_apply, payload, signature, 5.0)
    assert answer is not None, svc.log()
    return answer


def _signed(svc: Service, zones_hash: str, operator: str = "tester", key=None) -> tuple:
    payload = apply_payload(operator, zones_hash, cell="t5", boot=svc.status()["boot"])
    return payload, (key or svc.operator).sign(svc.keys.zones_apply, payload)


@pytest.mark.slow
def test_refused_applies_keep_the_zones_in_force(service):
    svc, tmp, cell, alerts = service
    before = svc.status()["config_hash"]
    original = cell.read_text()
    try:
        new_text = original + NEW_ZONE
        cell.write_text(new_text)
        new_hash = load_cell(cell).config_hash
        refusals = []
        # unsigned
        payload = apply_payload("tester", new_hash, cell="t5", boot=svc.status()["boot"])
        refusals.append(("unsigned", _ask(svc, payload, None)))
        # an operator the monitor does not list (a real key, signed correctly)
        private, _, _ = new_key_pair(tmp / "mallory.key")
        mallory = load_private_key(private)
        refusals.append(("unknown operator 'mallory'",
                         _ask(svc, *_signed(svc, new_hash, "mallory", mallory))))
        # signed the file, then the file changed (another zone moved) before the apply
        signed = _signed(svc, new_hash)
        cell.write_text(new_text.replace("[[150.0, 380.0], [420.0, 380.0]",
                                         "[[160.0, 380.0], [420.0, 380.0]"))
        refusals.append(("the file changed after you signed", _ask(svc, *signed)))
        # an invalid file (a self-intersecting polygon), whatever hash is signed
        cell.write_text(original + BOWTIE)
        refusals.append(("the zone file is invalid", _ask(svc, *_signed(svc, new_hash))))
        assert run_monitor("zones", "validate", cell).returncode != 0
        for needle, answer in refusals:
            assert answer["accepted"] is False and needle in answer["reason"], (needle, answer)
            assert "\n" not in answer["reason"]
        assert "self-intersecting" in refusals[-1][1]["reason"]
        # the old zones stay in force: status, commands, still SLOW (never STOP for the person)
        assert svc.status()["config_hash"] == before
        mark = len(svc.commands)
        time.sleep(1.0)
        later = svc.commands[mark:]
        assert later and all(c["config_hash"] == before for c in later)
        # never RUN, never STOP for the person (a loaded machine may add a stall STOP)
        assert all(c["state"] in ("SLOW", "STOP") and "protective_zone" not in codes(c)
                   for c in later), [codes(c) for c in later]
        refused = [a for a in alerts if a["kind"] == "zones_apply_refused"]
        assert refused and "unsigned" in refused[0]["message"], alerts  # (repeats rate-limited)
    finally:  # the next test starts from the shipped zones, whatever happened
        cell.write_text(original)


@pytest.mark.slow
def test_a_signed_apply_swaps_the_zones_a_person_in_the_new_zone_stops(service):
    svc, tmp, cell, alerts = service
    old = svc.status()["config_hash"]
    assert old == load_cell(cell).config_hash
    # not before: with the old zones the person standing there is SLOW, never STOP
    mark = len(svc.commands)
    time.sleep(1.0)
    before = svc.commands[mark:]
    # (a loaded machine may add a stall STOP: never one for the person, never RUN)
    assert before and all(c["config_hash"] == old and c["state"] in ("SLOW", "STOP")
                          and "protective_zone" not in codes(c) for c in before), \
        [(c["state"], codes(c)) for c in before]
    cell.write_text(cell.read_text() + NEW_ZONE)
    new = load_cell(cell).config_hash
    assert svc.status()["config_hash"] == old  # saved is not applied: nothing silent
    mark = len(svc.commands)
    proc = run_monitor("zones", "apply", "--operator", "tester", "--key", tmp / "tester.key",
                       "--cell", "t5", "--connect", f"tcp/127.0.0.1:{svc.bus_port}",
                       "--zones", cell, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "zones applied by tester" in proc.stdout
    i, first = svc.next_command(mark, lambda c: c["config_hash"] == new, 30, "the new hash")
    assert first["state"] == "STOP"  # the apply's own STOP comes with the new hash
    assert "zones_applying" in {r.get("fault") for r in first["reasons"]}
    svc.next_command(i, lambda c: "protective_zone" in codes(c)
                     and "zones_applying" not in {r.get("fault") for r in c["reasons"]}, 30,
                     "STOP for the person in the new protective zone")
    assert all(c["config_hash"] == new for c in svc.commands[i:])
    assert all(c["state"] != "RUN" and c["state"] != "SLOW" for c in svc.commands[i:])
    status = svc.status()
    assert status["config_hash"] == new
    assert status["zones_applied"]["operator"] == "tester"
    assert (status["zones_applied"]["old_hash"], status["zones_applied"]["new_hash"]) == (old,
                                                                                         new)
    applied = [a for a in alerts if a["kind"] == "zones_applied"]
    assert applied and applied[-1]["details"]["operator"] == "tester"
    assert applied[-1]["details"]["new_hash"] == new and applied[-1]["details"]["old_hash"] == old
    # the same request again is refused: that zone set is in force
    again = _ask(svc, *_signed(svc, new))
    assert not again["accepted"] and "already in force" in again["reason"]


@pytest.mark.slow
def test_a_console_save_that_shrinks_a_protective_zone_has_no_effect_until_a_signed_apply(
        service):
    """Issue 48: the admin's password, a console save (a protective zone shrunk away from the
    person) and a restart gave SLOW with the person inside. Now the save waits as a draft: the
    running monitor and the zone file (what a restart loads) keep the protective zone, the
    person stays STOP, until an operator signs the draft with `monitor zones apply`."""
    from starlette.testclient import TestClient

    from monitor.console.app import Console, build_app
    from monitor.console.audit import AuditLog
    from monitor.console.auth import Operators, set_password
    from monitor.console.incidents import NoIncidents
    from monitor.console.live import LiveRenderer, LiveState
    from monitor.console.zones_api import ZoneEditor
    from tests.console_kit import OPERATOR, PASSWORD, basic

    svc, tmp, cell, _ = service
    if "aisle-stop" not in cell.read_text():  # run alone: the new zone of the test above
        cell.write_text(cell.read_text() + NEW_ZONE)
        answer = _ask(svc, *_signed(svc, load_cell(cell).config_hash))
        assert answer["accepted"], answer
    in_force = load_cell(cell).config_hash
    svc.reach(len(svc.commands), lambda c: c["config_hash"] == in_force
              and "protective_zone" in codes(c), 60, "STOP: the person in aisle-stop")
    # the console over the service's own zone file (an operator's password)
    set_password(tmp / "console.pw", OPERATOR, PASSWORD, "operator")
    editor, live = ZoneEditor(cell), LiveState()
    console = Console("t5", live, LiveRenderer(live, editor.cell, {}), editor, NoIncidents(),
                      Operators(tmp / "console.pw"), AuditLog(tmp / "console.audit"), {})
    client = TestClient(build_app(console))
    before = cell.read_bytes()
    r = client.put("/api/zones/aisle-stop", json={
        "points_px": [[150.0, 380.0], [200.0, 380.0], [200.0, 420.0], [150.0, 420.0]],
        "base": client.get("/api/zones").json()["sha"]}, headers=basic(OPERATOR, PASSWORD))
    assert r.status_code == 202, r.text
    assert "aisle-stop shrunk or moved" in r.json()["draft"]["weakens"][0]
    assert cell.read_bytes() == before  # a restart loads the protective zone as it was
    assert load_cell(cell).config_hash == in_force == svc.status()["config_hash"]
    mark = len(svc.commands)
    time.sleep(1.5)
    assert all(c["config_hash"] == in_force and c["state"] == "STOP"
               for c in svc.commands[mark:])  # no effect: the person is still a STOP
    draft = draft_path(cell)
    weaker = load_cell(draft).config_hash
    proc = run_monitor("zones", "apply", "--operator", "tester", "--key", tmp / "tester.key",
                       "--cell", "t5", "--connect", f"tcp/127.0.0.1:{svc.bus_port}",
                       "--zones", draft, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # the person latched the STOP in aisle-stop: on the signed zones it no longer holds them
    svc.next_command(mark, lambda c: c["config_hash"] == weaker and c["reset_possible"], 60,
                     "on the signed zones the person no longer in a protective zone")
    assert not draft.exists() and load_cell(cell).config_hash == weaker  # the file is it now


def test_the_cli_refuses_an_invalid_file_before_sending(tmp_path):
    cell = tmp_path / "cell.yaml"
    cell.write_text(Path(demo_cell_path()).read_text() + BOWTIE)
    proc = run_monitor("zones", "apply", "--operator", "tester", "--cell", "t5", "--connect",
                       "tcp/127.0.0.1:9", "--zones", cell, timeout=60)
    assert proc.returncode == 2 and "self-intersecting" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) <= 2  # the key note and the one-line error


def test_a_swap_stops_for_at_least_one_decision_and_clear_time_on_the_new_zones(detector,
                                                                                tmp_path):
    """Even when the first frame after the swap comes in the very next step, the cell STOPs
    (zones_applying) and RUN waits clear_time on the new zones (fails without the forced STOP:
    the swap would go from RUN to RUN)."""
    from monitor.pipeline import Pipeline
    from monitor.policy import PolicyConfig
    from monitor.types import FrameInfo

    image = next(iter(DemoScene().frames()))[0]  # nobody in the cell yet
    cell = load_cell(demo_cell_path())
    policy = PolicyConfig()
    pipeline = Pipeline(detector, ["cam0"], policy, cell)
    h, w = image.shape[:2]
    t, seq, states = 0.0, 0, []

    def step() -> str:
        nonlocal t, seq
        t += 0.1
        seq += 1
        result = pipeline.process(image, FrameInfo("cam0", seq, t, w, h), t)
        return result.command

    while (cmd := step()).state != "RUN":
        assert t < 10
    changed = tmp_path / "cell.yaml"
    changed.write_text(Path(demo_cell_path()).read_text() + NEW_ZONE)
    pipeline.swap_cell(load_cell(changed), note=" by tester")
    swapped_at = t
    first = step()
    assert first.state == "STOP" and not first.latched  # a start on new zones: no reset
    assert "zones_applying" in {r.fault for r in first.reasons}
    while (cmd := step()).state != "RUN":
        states.append(cmd.state)
        assert t < swapped_at + 10
    assert t - (swapped_at + 0.1) >= policy.clear_time - 1e-6  # clear_time on the new zones
    assert pipeline.cell.config_hash == load_cell(changed).config_hash and not states.count("RUN")
