"""Bounded muting (docs/muting.md): the pure rules, and through the real pipeline with
generated frames a person in a muted protective zone SLOWs, and STOPs in the first frame
after the mute's end."""

from __future__ import annotations

import copy

import pytest

from monitor.cases.muting import DEFAULT_MUTED_SCALE, MuteRequest, Mutes, mute_rules
from monitor.errors import ConfigError
from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig, ResetRequest
from monitor.scene.cell import CellScene, Walker, zone_data
from monitor.types import FrameInfo, ZoneHit, ZoneReport
from monitor.zones.check import apply_mutes
from monitor.zones.files import parse_cell

SCENE = CellScene((Walker(((0.0, 0.0, 0.3),), appear_s=1.5),), fps=10.0, duration_s=4.0)
MUTE = {"max_s": 120.0, "operators": ["anna", "bob"]}


def cell_data(mute: dict | None = MUTE, **protective) -> dict:
    data = zone_data(SCENE)
    zone = data["zones"][0]
    assert zone["id"] == "robot-protective"
    if mute is not None:
        zone["mute"] = copy.deepcopy(mute)
    zone.update(protective)
    return data


def req(zone="robot-protective", operator="anna", duration_s=60.0, rid="r1", t=0.0,
        end=False) -> MuteRequest:
    return MuteRequest(zone, operator, duration_s, rid, t, end=end)


@pytest.fixture()
def mutes() -> Mutes:
    return Mutes.of(parse_cell(cell_data()))


# --- the pure rules ---------------------------------------------------------------------------


def test_a_mute_longer_than_the_zones_maximum_is_refused(mutes):
    state, out = mutes.request(req(duration_s=120.5), now=10.0)
    assert not out.accepted and "longer than" in out.reason and "120 s" in out.reason
    assert state.muted_zones(10.0) == {}
    state, out = mutes.request(req(duration_s=120.0, rid="r2"), now=10.0)
    assert out.accepted, out.reason


def test_an_operator_not_listed_for_the_zone_is_refused(mutes):
    state, out = mutes.request(req(operator="carl"), now=1.0)
    assert not out.accepted and "'carl' is not allowed" in out.reason
    assert state.muted_zones(1.0) == {}


@pytest.mark.parametrize("data", [
    cell_data(mute=None),  # protective without mute: unmutable by default
    cell_data(mute=None, unmutable=True),
])
def test_an_unmutable_zone_is_refused(data):
    state, out = Mutes.of(parse_cell(data)).request(req(), now=1.0)
    assert not out.accepted and "cannot be muted" in out.reason
    assert state.muted_zones(1.0) == {}


def test_unmutable_and_mute_together_is_a_zone_file_error():
    with pytest.raises(ConfigError, match=r"robot-protective.*unmutable"):
        parse_cell(cell_data(unmutable=True))


def test_mute_on_a_mask_or_a_warning_zone_muted_as_warning_is_a_zone_file_error():
    data = cell_data(mute=None)
    data["zones"][1]["mute"] = {"max_s": 10.0, "operators": ["anna"], "as": "warning"}
    with pytest.raises(ConfigError, match="changes nothing"):
        parse_cell(data)
    data["zones"][1]["mute"]["as"] = "none"
    assert mute_rules(parse_cell(data))["robot-warning"].mutable


def test_expiry_is_exact_at_the_maximum(mutes):
    state, out = mutes.request(req(duration_s=120.0), now=100.0)
    assert out.accepted
    assert state.muted_zones(100.0) == {"robot-protective": 0.3}  # the slowest warning scale
    assert state.muted_zones(219.999999) == {"robot-protective": 0.3}
    assert state.muted_zones(220.0) == {}
    assert state.muted_zones(float("nan")) == {}
    state2, ended = state.expire(220.0)
    assert [m.zone for m in ended] == ["robot-protective"] and state2.active == ()
    assert state.expire(219.9)[1] == ()


def test_a_replayed_request_is_refused_even_after_the_mute_ended(mutes):
    state, out = mutes.request(req(duration_s=5.0), now=0.0)
    assert out.accepted
    state, out = state.request(req(duration_s=5.0), now=10.0)  # same request id, later
    assert not out.accepted and "replayed" in out.reason


def test_a_mute_is_never_extended_and_can_be_ended_early(mutes):
    state, _ = mutes.request(req(duration_s=100.0), now=0.0)
    state, again = state.request(req(duration_s=100.0, rid="r2"), now=90.0)
    assert not again.accepted and "already muted" in again.reason
    assert state.muted_zones(100.0) == {}  # the first one still ends at 100 s
    state, _ = mutes.request(req(duration_s=100.0, rid="r3"), now=0.0)
    state, end = state.request(req(rid="r4", end=True, operator="carl"), now=5.0)
    assert end.accepted and end.mute.end == 5.0 and state.muted_zones(5.0) == {}


def test_no_zone_file_and_unknown_zones_mute_nothing():
    _, out = Mutes.of(None).request(req(), now=0.0)
    assert not out.accepted
    _, out = Mutes.of(parse_cell(cell_data())).request(req(zone="nope"), now=0.0)
    assert not out.accepted and "no enabled protective or warning zone 'nope'" in out.reason


def test_apply_mutes_as_warning_and_as_none():
    hits = (ZoneHit("P", "protective", 0, 0.0, 0.0), ZoneHit("W", "warning", 0, 0.3, 0.0),
            ZoneHit("P", "protective", 1, 0.0, None, track_id=4, lost=True, lost_since=1.0))
    report = ZoneReport(hits=hits, tool_separation_m=0.2, required_separation_m=0.5)
    slow = apply_mutes(report, {"P": 0.25})
    assert [(h.kind, h.speed_scale, h.lost) for h in slow.hits] == [
        ("warning", 0.25, False), ("warning", 0.3, False), ("warning", 0.25, True)]
    assert slow.required_separation_m == 0.5  # separation is never muted
    assert [h.zone_id for h in apply_mutes(report, {"P": None}).hits] == ["W"]
    assert apply_mutes(report, {}) is report


def test_as_none_and_the_default_scale_without_warning_zones():
    data = cell_data(mute={**MUTE, "as": "none"})
    assert Mutes.of(parse_cell(data)).request(req(), 0.0)[0].muted_zones(0.0) == {
        "robot-protective": None}
    data = cell_data()
    del data["zones"][1]
    assert Mutes.of(parse_cell(data)).request(req(), 0.0)[0].muted_zones(0.0) == {
        "robot-protective": DEFAULT_MUTED_SCALE}
    data = cell_data(mute={**MUTE, "speed_scale": 0.05})
    assert Mutes.of(parse_cell(data)).request(req(), 0.0)[0].muted_zones(0.0) == {
        "robot-protective": 0.05}


# --- through the real pipeline ----------------------------------------------------------------


def test_a_person_in_a_muted_protective_zone_slows_and_stops_in_the_first_frame_after_expiry(
        detector):
    """The person stands inside robot-protective from 1.5 s; anna mutes it at 0.5 s for 3 s
    (its maximum is 120 s): SLOW while muted (never RUN, never STOP), STOP at the 3.5 s frame,
    the first one at or after the end. On the old code nothing can be muted: STOP at 1.5 s."""
    pipe = Pipeline(detector, "cam0", PolicyConfig(clear_time=0.5), parse_cell(cell_data()))
    results = {}
    for image, truth in SCENE.frames():
        t = round(truth.time_s, 6)
        if t == 0.5:
            (outcome,) = pipe.request_mutes([req(duration_s=3.0, t=t)], t)
            assert outcome.accepted, outcome.reason
        info = FrameInfo("cam0", round(t * SCENE.fps), t, image.shape[1], image.shape[0])
        results[t] = pipe.process(image, info, t)
    states = {t: r.command.state for t, r in results.items()}
    muted = [t for t in states if 1.5 <= t < 3.5]
    assert muted and all(states[t] == "SLOW" for t in muted), states
    for t in muted:
        reasons = results[t].command.reasons
        assert any(r.code == "muted" and "muted by anna" in r.message for r in reasons)
        assert not any(r.code == "protective_zone" for r in reasons)
        assert results[t].command.speed_scale == pytest.approx(0.3)
    assert states[3.5] == "STOP", states
    assert any(r.code == "protective_zone" for r in results[3.5].command.reasons)
    assert not any(r.code == "muted" for r in results[3.5].command.reasons)
    assert all(states[t] == "STOP" for t in states if t >= 3.5)
    kinds = {t: [a.kind for a in r.alerts] for t, r in results.items()}
    assert "zone_muted" in kinds[0.5] and "zone_unmuted" in kinds[3.5], kinds
    started = next(a for a in results[0.5].alerts if a.kind == "zone_muted")
    assert started.details["operator"] == "anna"
    assert started.details["zone"] == "robot-protective"
    assert [o.accepted for o in results[0.5].mute_outcomes] == [True]
    assert results[3.4].mutes and not results[3.5].mutes


def test_mute_rules_are_part_of_the_config_hash_and_older_files_keep_theirs():
    plain = parse_cell(cell_data(mute=None)).config_hash
    assert parse_cell(cell_data(mute=None, unmutable=None)).config_hash == plain
    assert parse_cell(cell_data()).config_hash != plain
    longer = parse_cell(cell_data(mute={**MUTE, "max_s": 600.0})).config_hash
    assert longer not in (plain, parse_cell(cell_data()).config_hash)
    assert parse_cell(cell_data(mute=None, unmutable=True)).config_hash != plain


def test_a_zone_file_with_mute_writes_back_as_it_reads():
    from monitor.zones.files import cell_to_data

    cell = parse_cell(cell_data(mute={**MUTE, "as": "none"}))
    data = cell_to_data(cell)
    assert data["zones"][0]["mute"]["as"] == "none"
    assert parse_cell(data).config_hash == cell.config_hash


def test_a_reset_with_the_protective_zone_muted_and_a_person_inside_is_refused_naming_it(
        detector):
    """Issue 48, the scanners' rule (docs/muting.md, "Resets while muted"): a person walks into
    robot-protective (STOP, latched); anna mutes it; a reset while the person is still inside
    is refused naming the muted zone (before: accepted, SLOW x0.3 with the person inside); once
    the person is seen out of it the same reset is accepted, the mute still holding."""
    walk = Walker(((0.0, 0.45, 0.0), (3.0, 0.45, 0.0), (4.5, 3.4, 0.0)), appear_s=1.0)
    scene = CellScene((walk,), fps=10.0, duration_s=5.6)
    pipe = Pipeline(detector, "cam0", PolicyConfig(clear_time=0.5),
                    parse_cell(zone_data(scene) | {"zones": cell_data()["zones"]}))
    results = {}
    for image, truth in scene.frames():
        t = round(truth.time_s, 6)
        if t == 1.5:
            (outcome,) = pipe.request_mutes([req(duration_s=60.0, t=t)], t)
            assert outcome.accepted, outcome.reason
        reset = ResetRequest("anna", t, f"reset-{t}") if t in (2.0, 5.5) else None
        info = FrameInfo("cam0", round(t * scene.fps), t, image.shape[1], image.shape[0])
        results[t] = pipe.process(image, info, t, reset=reset)
    assert results[1.4].command.state == "STOP" and results[1.4].command.latched
    muted = results[1.9].command
    assert muted.state == "STOP" and muted.latched and not muted.reset_possible
    assert any(r.code == "muted" for r in muted.reasons)
    assert muted.reasons[0].code == "latched" and \
        "no reset until muted robot-protective seen free" in muted.reasons[0].message
    assert "muted zone robot-protective not seen free" in muted.describe()
    refused = results[2.0].command
    assert refused.reset is not None and not refused.reset.accepted
    assert refused.reset.message.startswith("refused: muted zone robot-protective not seen "
                                            "free (person ")
    assert "never makes a reset with a person inside acceptable" in refused.reset.message
    assert all(results[t].command.state == "STOP" for t in results if 2.0 <= t < 5.5)
    accepted = results[5.5].command
    assert accepted.reset is not None and accepted.reset.accepted, accepted.reset
    assert accepted.state != "STOP" and any(r.code == "muted" for r in accepted.reasons)
    assert results[5.4].command.reset_possible  # seen free: said before the reset came
