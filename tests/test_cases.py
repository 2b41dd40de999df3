"""Zone sets switched by the robot program (docs/cases.md): the pure switch-over logic, the
signed selection gate, the zone file keys, and a station A/B scene through the real Pipeline."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

from monitor.cases import sets as cs
from monitor.cases.requests import CaseGate, CasePolicy, CaseRefused, case_payload
from monitor.config import demo_cell_path
from monitor.errors import ConfigError
from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig
from monitor.scene import DemoScene, Figure, draw_figure
from monitor.types import FrameInfo, ZoneHit, ZoneReport
from monitor.wire.signing import Signer
from monitor.zones import parse_cell

POLICY = PolicyConfig(clear_time=0.5, restart_interlock="auto")
PLAN = cs.CasePlan(
    sets=(cs.ZoneSet("A", frozenset({"station-a"})), cs.ZoneSet("B", frozenset({"station-b"}))),
    default="A", transitions=frozenset({("A", "B"), ("B", "A")}), switch_over_s=1.0,
    selector_ttl_s=2.0)


# ------------------------------------------------------------------ the pure switch-over logic

def test_a_switch_applies_the_union_for_switch_over_s_then_only_the_new_set():
    state = cs.initial_case(PLAN, 0.0)
    assert cs.in_force(PLAN, state, 0.5).dropped == {"station-b"}
    state = cs.apply_event(PLAN, state, cs.Selection("B", "robot", 1), 1.0)
    during = cs.in_force(PLAN, state, 1.99)
    assert during.sets == ("A", "B") and during.dropped == frozenset() and during.switching
    after = cs.in_force(PLAN, state, 2.0)
    assert after.sets == ("B",) and after.dropped == {"station-a"} and not after.faults


def test_a_second_switch_during_the_switch_over_keeps_every_set_applying():
    plan = cs.CasePlan((*PLAN.sets, cs.ZoneSet("C", frozenset({"station-c"}))), "A",
                       switch_over_s=1.0)
    state = cs.apply_event(plan, cs.initial_case(plan, 0.0), cs.Selection("B"), 1.0)
    state = cs.apply_event(plan, state, cs.Selection("C"), 1.5)
    assert cs.in_force(plan, state, 2.2).sets == ("A", "B", "C")  # A has not ended at 2.0
    assert cs.in_force(plan, state, 2.5).sets == ("C",)


def test_a_disallowed_transition_is_a_stop_fault_and_the_old_set_stays():
    plan = cs.CasePlan(PLAN.sets, "A", transitions=frozenset({("B", "A")}))
    state = cs.apply_event(plan, cs.initial_case(plan, 0.0), cs.Selection("B", "robot"), 1.0)
    now = cs.in_force(plan, state, 3.0)
    assert [f.name for f in now.faults] == ["case_disallowed"] and now.faults[0].stop
    assert "not an allowed transition" in now.faults[0].reason
    assert now.sets == ("A",)
    # the next valid selection clears it
    state = cs.apply_event(plan, state, cs.Selection("A", "robot"), 3.5)
    assert cs.in_force(plan, state, 3.6).faults == ()


def test_an_unknown_set_is_a_stop_fault_naming_the_set():
    state = cs.apply_event(PLAN, cs.initial_case(PLAN, 0.0), cs.Selection("Z", "robot"), 0.5)
    faults = cs.in_force(PLAN, state, 0.6).faults
    assert [f.name for f in faults] == ["case_unknown"] and "'Z'" in faults[0].reason
    assert cs.in_force(PLAN, state, 0.6).sets == ("A",)


def test_a_selector_silent_beyond_its_ttl_is_a_stop_fault_until_it_speaks():
    state = cs.initial_case(PLAN, 0.0)
    assert cs.in_force(PLAN, state, 2.0).faults == ()
    faults = cs.in_force(PLAN, state, 2.05).faults
    assert [f.name for f in faults] == ["case_selector_silent"] and faults[0].stop
    state = cs.apply_event(PLAN, state, cs.Selection("A", "robot", 5), 2.5)  # a heartbeat
    assert cs.in_force(PLAN, state, 4.4).faults == ()
    assert cs.in_force(PLAN, state, 4.6).faults[0].name == "case_selector_silent"


def test_a_refused_request_changes_nothing_and_is_no_fault():
    """One unsigned packet on safety/case was a latched STOP: a one-packet denial of service.
    It comes from no selector, so it changes no set and stops nothing."""
    start = cs.initial_case(PLAN, 0.0)
    state = cs.apply_event(PLAN, start, cs.Refusal("unsigned selection in the name of "
                                                   "'robot'", "robot"), 0.2)
    assert state == start and cs.in_force(PLAN, state, 0.3).faults == ()
    # mid-switch-over: the union stays as it was
    switching = cs.apply_event(PLAN, start, cs.Selection("B", "robot", 1), 0.4)
    after = cs.apply_event(PLAN, switching, cs.Refusal("replayed", "robot"), 0.5)
    assert after == switching


def test_hits_of_zones_of_sets_not_applying_do_not_count_and_set_caps_slow_warning_hits():
    plan = cs.CasePlan((cs.ZoneSet("A", frozenset({"station-a", "warn-a"}), 0.2),
                        cs.ZoneSet("B", frozenset({"station-b"}))), "A")
    report = ZoneReport(hits=(ZoneHit("station-b", "protective", 0, 0.0),
                              ZoneHit("warn-a", "warning", 1, 0.5),
                              ZoneHit("fence", "protective", 2, 0.0)))
    out = cs.filter_report(report, cs.in_force(plan, cs.initial_case(plan, 0.0), 0.0))
    assert [(h.zone_id, h.speed_scale) for h in out.hits] == [("warn-a", 0.2), ("fence", 0.0)]


# ------------------------------------------------------------------ the signed request gate

def _gate():
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    key = Ed25519PrivateKey.generate()
    gate = CaseGate(CasePolicy({"robot": key.public_key()}, "cell1",
                               "workcell/cell1/safety/case", window_s=5.0))
    return gate, Signer(key)


def test_a_signed_selection_is_accepted_and_replayed_or_stale_ones_are_refused():
    gate, signer = _gate()
    key = gate.policy.key_expr
    body = case_payload("robot", "B", 7, cell="cell1", wall=1000.0)
    assert gate.check(body, signer.sign(key, body), 1000.5) == cs.Selection("B", "robot", 7)
    with pytest.raises(CaseRefused, match="replayed"):  # the same request again
        gate.check(body, signer.sign(key, body), 1000.6)
    older = case_payload("robot", "A", 6, cell="cell1", wall=1000.7)
    with pytest.raises(CaseRefused, match="not above its last 7"):
        gate.check(older, signer.sign(key, older), 1000.8)
    stale = case_payload("robot", "A", 8, cell="cell1", wall=990.0)
    with pytest.raises(CaseRefused, match="off the monitor's clock"):
        gate.check(stale, signer.sign(key, stale), 1000.8)
    with pytest.raises(CaseRefused, match="unsigned"):
        gate.check(case_payload("robot", "A", 9, wall=1000.0), None, 1000.8)
    forged = case_payload("robot", "A", 9, wall=1000.0)
    with pytest.raises(CaseRefused, match="signature does not match"):
        gate.check(forged, signer.sign("workcell/cell2/safety/case", forged), 1000.8)
    refusal = gate.judge(b"{not json", None, 1000.8)
    assert isinstance(refusal, cs.Refusal) and "not JSON" in refusal.reason


# ------------------------------------------------------------------ zone file keys

def _station_cell(default: str = "A", **extra) -> dict:
    """The demo cell's camera with two stations: A left of the robot, B right of it."""
    data = yaml.safe_load(demo_cell_path().read_text())
    data["zones"] = [
        {"id": "station-a", "kind": "protective", "shape": "box",
         "min_m": [-2.6, -1.6, 0.0], "max_m": [-1.0, 0.4, 2.2]},
        {"id": "station-b", "kind": "protective", "shape": "box",
         "min_m": [1.0, -1.6, 0.0], "max_m": [2.6, 0.4, 2.2]},
    ]
    data["sets"] = [{"id": "A", "zones": ["station-a"]}, {"id": "B", "zones": ["station-b"]}]
    data["default_set"] = default
    data["transitions"] = [["A", "B"], ["B", "A"]]
    data["switch_over_s"] = 1.0
    data.update(extra)
    return data


@pytest.mark.parametrize(("change", "needle"), [
    (lambda d: d.update(default_set="C"), "default_set: no set 'C'"),
    (lambda d: d.pop("default_set"), "default_set: missing"),
    (lambda d: d["sets"][0].update(zones=["nowhere"]), "set 'A': no zone 'nowhere'"),
    (lambda d: d.update(transitions=[["A", "Q"]]), "names no set 'Q'"),
    (lambda d: d.update(sets=[], default_set="A"), "default_set: given but the file declares"),
    (lambda d: d.update(switch_over_s=-1.0), "switch_over_s"),
])
def test_a_wrong_set_key_is_one_line_naming_it(change, needle):
    data = copy.deepcopy(_station_cell())
    change(data)
    with pytest.raises(ConfigError, match=needle) as err:
        parse_cell(data)
    assert "\n" not in str(err.value)


def test_sets_change_the_config_hash_and_files_without_sets_keep_theirs():
    with_sets = parse_cell(_station_cell())
    plain = _station_cell()
    for key in ("sets", "default_set", "transitions", "switch_over_s"):
        plain.pop(key)
    other = parse_cell(_station_cell(switch_over_s=2.0))
    assert len({with_sets.config_hash, parse_cell(plain).config_hash, other.config_hash}) == 3


# ------------------------------------------------------------------ the station A/B scene

def _frame_with_person_at(x_m: float, y_m: float, seq: int, t: float):
    scene = DemoScene()
    img = scene.background()
    img[::7, ::5] += np.uint8(seq % 3)  # a live camera: consecutive frames differ
    if x_m is not None:
        feet = scene.camera.project(np.array([[x_m, y_m, 0.0], [x_m, y_m, 1.75]]))
        draw_figure(img, Figure((float(feet[0][0]), float(feet[0][1])),
                                float(feet[0][1] - feet[1][1])))
    return img, FrameInfo("cam0", seq, t, 1280, 720)


def _run(pipe: Pipeline, t0: float, t1: float, fps: float = 10.0, seq0: int = 0,
         events_at: dict | None = None):
    """Frames of a person at station B from t0 to t1; ``events_at`` {time: [event]}."""
    out = []
    n = round((t1 - t0) * fps)
    for k in range(n):
        t = round(t0 + k / fps, 6)
        for event_t, events in (events_at or {}).items():
            if abs(event_t - t) < 1e-9:
                pipe.take_case_events(events, t)
        img, info = _frame_with_person_at(1.8, -0.6, seq0 + k, t)
        out.append(pipe.process(img, info, t))
    return out


def test_a_person_at_station_b_gives_run_with_set_a_and_stop_with_set_b(detector):
    with_a = Pipeline(detector, "cam0", POLICY, parse_cell(_station_cell("A")))
    results = _run(with_a, 0.0, 1.2)
    assert results[-1].command.state == "RUN" and results[-1].command.zone_sets == ("A",)
    with_b = Pipeline(detector, "cam0", POLICY, parse_cell(_station_cell("B")))
    results = _run(with_b, 0.0, 1.2)
    assert all(r.command.state == "STOP" for r in results)
    last = results[-1].command
    assert last.zone_sets == ("B",)
    assert any(r.zone_id == "station-b" for r in last.reasons)
    assert last.to_dict()["zone_sets"] == ["B"]


def test_switching_a_to_b_with_the_person_in_b_stops_from_the_request_on(detector):
    pipe = Pipeline(detector, "cam0", POLICY, parse_cell(_station_cell("A")))
    before = _run(pipe, 0.0, 1.0)
    assert before[-1].command.state == "RUN"
    after = _run(pipe, 1.0, 3.0, seq0=10, events_at={1.0: [cs.Selection("B", "robot", 1)]})
    during = [r for r in after if r.now < 2.0]
    assert during and all(r.command.state == "STOP" for r in during)  # never a RUN frame
    assert during[0].command.zone_sets == ("A", "B") and during[0].changed
    assert all(r.command.state == "STOP" for r in after)
    assert after[-1].command.zone_sets == ("B",)


def test_switching_b_to_a_keeps_b_during_the_switch_over_then_runs(detector):
    pipe = Pipeline(detector, "cam0", POLICY, parse_cell(_station_cell("B")))
    _run(pipe, 0.0, 1.0)
    after = _run(pipe, 1.0, 3.5, seq0=10, events_at={1.0: [cs.Selection("A", "robot", 1)]})
    assert all(r.command.state == "STOP" for r in after if r.now < 2.0)  # the union holds B
    assert after[-1].command.state == "RUN" and after[-1].command.zone_sets == ("A",)


def test_a_selector_falling_silent_stops_the_cell_with_the_reason(detector):
    pipe = Pipeline(detector, "cam0", POLICY, parse_cell(_station_cell("A", selector_ttl_s=1.0)))
    results = _run(pipe, 0.0, 2.0, events_at={0.5: [cs.Selection("A", "robot", 1)]})
    assert results[14].command.state == "RUN"  # t = 1.4: heard at 0.5
    late = results[-1].command  # t = 1.9 > 0.5 + ttl
    assert late.state == "STOP"
    assert any(r.fault == "case_selector_silent" for r in late.reasons)


def test_an_unknown_set_stops_the_cell_with_the_reason_a_refused_request_does_not(detector):
    pipe = Pipeline(detector, "cam0", POLICY, parse_cell(_station_cell("A")))
    results = _run(pipe, 0.0, 2.0, events_at={
        1.0: [cs.Selection("Z", "robot", 1)],
        1.5: [cs.Refusal("seq 1 of 'robot' is not above its last 1 (replayed)", "robot")]})
    assert results[9].command.state == "RUN"
    unknown = results[10].command
    assert unknown.state == "STOP" and "unknown zone set 'Z'" in unknown.describe()
    replayed = results[-1].command  # the unknown set's fault holds; the refusal adds none
    assert replayed.state == "STOP" and "replayed" not in replayed.describe()
    assert {r.fault for r in replayed.reasons} == {"case_unknown"}


def test_the_sets_in_force_are_in_the_annotated_header_and_the_replay_events(detector):
    from monitor.records.annotate import header_text
    from monitor.replay.video import command_event

    pipe = Pipeline(detector, "cam0", POLICY, parse_cell(_station_cell("A")))
    _run(pipe, 0.0, 0.3)
    result = _run(pipe, 0.3, 0.4, seq0=3, events_at={0.3: [cs.Selection("B", "robot", 1)]})[0]
    assert header_text(result, "cam0").endswith("sets A+B  (switching)")
    assert command_event(result, 3)["zone_sets"] == ["A", "B"]


def test_a_file_without_sets_is_written_without_set_keys_and_one_with_them_round_trips():
    from monitor.zones import cell_to_data

    plain = cell_to_data(parse_cell(yaml.safe_load(demo_cell_path().read_text())))
    assert not {"sets", "switch_over_s", "default_set", "transitions"} & set(plain)
    cell = parse_cell(_station_cell())
    again = parse_cell(cell_to_data(cell))
    assert again.config_hash == cell.config_hash and again.spec.default_set == "A"


def test_selections_held_back_on_the_path_are_a_silent_selector_not_a_heartbeat():
    """The attack: someone on the path holds the robot program's signed heartbeats back 3 s
    and hands them on in order. Each is genuine, in sequence and inside the 5 s window, so the
    first version took each as a fresh heartbeat: the monitor kept applying the set of 3 s ago
    (a switch to another station's zones 3 s late) without a fault. A selection is now heard
    as of when it was sent: 3 s late with ``selector_ttl_s`` 2 s is ``case_selector_silent``."""
    gate, signer = _gate()
    key = gate.policy.key_expr
    state = cs.initial_case(PLAN, 0.0)
    for i in range(1, 40):  # 4 s of heartbeats at 10 Hz, each sent 3 s before it arrives
        now = i / 10
        body = case_payload("robot", "A", i, cell="cell1", wall=1000.0 + now - 3.0)
        event = gate.check(body, signer.sign(key, body), 1000.0 + now)
        state = cs.apply_event(PLAN, state, event, now)
    assert [f.name for f in cs.in_force(PLAN, state, 3.9).faults] == ["case_selector_silent"]
    # on time, the same stream is a heartbeat
    gate, signer = _gate()
    state = cs.initial_case(PLAN, 0.0)
    for i in range(1, 40):
        now = i / 10
        body = case_payload("robot", "A", i, cell="cell1", wall=1000.0 + now - 0.05)
        state = cs.apply_event(PLAN, state, gate.check(body, signer.sign(key, body),
                                                       1000.0 + now), now)
    assert cs.in_force(PLAN, state, 3.9).faults == ()
