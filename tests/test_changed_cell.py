"""What changed since commissioning (monitor/health/objects.py, docs/occlusion.md): an object
put into the protective zone after the reference was taken holds the cell and hides the floor
behind it; lighting changes and persons are no objects."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from monitor.health.objects import OBJECT_IN_ZONE, OBJECT_PLACED, VIEW_CHANGED
from monitor.pipeline import Pipeline
from monitor.policy import STOP, PolicyConfig, ResetRequest
from monitor.replay import scenarios as sc
from monitor.scene.cell import Block, CellScene, Walker
from monitor.types import FrameInfo
from monitor.wire.object_accepts import AcceptGate, accept_payload
from monitor.wire.signing import Signer
from monitor.zones import parse_cell

FPS = 5.0


ANNA = Signer(Ed25519PrivateKey.generate())
ACCEPT_KEY = "workcell/cell1/safety/objects/accept"


def signed_accept(gate: AcceptGate, t: float, camera: str = "cam0",
                  zone: str = "robot-protective", signer: Signer = ANNA,
                  request_id: str = ""):
    """Anna's acceptance as the bus hands it on: signed with her key, checked by the gate."""
    payload = accept_payload("anna", camera, zone, cell="cell1", boot="b1",
                             request_id=request_id, note="a crate of parts, looked behind it")
    return gate.check(payload, signer.sign(ACCEPT_KEY, payload), t, boot="b1")


def run(detector, scenario: sc.Scenario, *, reference: bool = True, gain: float = 1.0,
        confirm_at: float | None = None, accept_at: float | None = None, faults=None,
        light=None):
    """Frames through the pipeline with a plain reset every 0.5 s (a confirm-clear one at
    ``confirm_at``; anna's signed acceptance of the object in the protective zone at
    ``accept_at``): (states, inside flags, reset outcomes, alerts). ``faults``: a list that
    gets each step's fault names; ``light``: a function applied to every frame."""
    cell = parse_cell(scenario.zone_data())
    cam = scenario.scene.camera
    refs = {cam.camera_id: scenario.scene.reference()} if reference else None
    pipe = Pipeline(detector, cam.camera_id, PolicyConfig(), cell, references=refs)
    gate = AcceptGate({"anna": ANNA.key.public_key()}, "cell1", ACCEPT_KEY)
    states, inside, outcomes, alerts = [], [], [], []
    next_reset = 0.5
    confirmed = accepted = False
    for k, (img, truth) in enumerate(scenario.scene.frames()):
        t = truth.time_s
        if gain != 1.0:
            img = np.clip(img.astype(np.float32) * gain, 0, 255).astype(np.uint8)
        if light is not None:
            img = light(img)
        if accept_at is not None and not accepted and t + 1e-9 >= accept_at:
            (outcome,) = pipe.accept_objects([signed_accept(gate, t)], t)
            assert outcome.accepted, outcome.reason
            accepted = True
        reset = None
        if confirm_at is not None and not confirmed and t + 1e-9 >= confirm_at:
            reset = ResetRequest("anna", t, request_id=f"c{k}", confirm_clear=True)
            confirmed = True
        elif t + 1e-9 >= next_reset:
            reset = ResetRequest("eval", t, request_id=f"r{k}")
            next_reset += 0.5
        res = pipe.process(img, FrameInfo(cam.camera_id, k, t, cam.width, cam.height), t,
                           reset=reset)
        states.append(res.command.state)
        inside.append(any(max(abs(p.floor_m[0]), abs(p.floor_m[1])) < 1.0
                          + cell.spec.person.radius_m for p in truth.persons))
        outcomes.append(None if res.command.reset is None else res.command.reset)
        alerts.extend(res.alerts)
        if faults is not None:
            faults.append({f.name for f in res.faults})
    return states, inside, [o if o is None else o.accepted for o in outcomes], alerts


def reset_messages(detector, scenario, **kw) -> list[str]:
    """The refusal texts of the plain resets (for what they name)."""
    cell = parse_cell(scenario.zone_data())
    cam = scenario.scene.camera
    pipe = Pipeline(detector, cam.camera_id, PolicyConfig(), cell,
                    references={cam.camera_id: scenario.scene.reference()})
    out = []
    for k, (img, truth) in enumerate(scenario.scene.frames()):
        t = truth.time_s
        res = pipe.process(img, FrameInfo(cam.camera_id, k, t, cam.width, cam.height), t,
                           reset=ResetRequest("eval", t, request_id=f"r{k}"))
        if res.command.reset is not None and not res.command.reset.accepted:
            out.append(res.command.reset.message)
    return out


def crate_scene() -> sc.Scenario:
    return sc.select(["crate-after-reference"], FPS)[0]


def test_a_crate_put_into_the_zone_after_commissioning_holds_a_person_crouching_behind_it(
        detector):
    states, inside, outcomes, alerts = run(detector, crate_scene())
    assert any(inside)
    assert all(s == STOP for s, i in zip(states, inside, strict=True) if i)
    assert not any(o for o, i in zip(outcomes, inside, strict=True) if i)
    placed = [a for a in alerts if a.kind == OBJECT_PLACED]
    assert len(placed) == 1, [a.message for a in alerts]
    a = placed[0]
    # names the camera, the zone and the floor place, with a snapshot
    assert a.source == "cam0" and "robot-protective" in a.details["zones"]
    x, y = a.details["floor_m"]
    assert 0.0 < x < 1.0 and -1.0 < y < -0.2, a.message
    assert a.snapshot_jpeg and "x 0." in a.message


def test_without_the_reference_the_crate_case_is_missed(detector):
    # the test above can fail: nothing compares the view with commissioning day
    states, inside, outcomes, _ = run(detector, crate_scene(), reference=False)
    missed = sum(s != STOP for s, i in zip(states, inside, strict=True) if i)
    accepted = sum(bool(o) for o, i in zip(outcomes, inside, strict=True) if i)
    assert missed > 0 or accepted > 0


def test_accepted_by_an_operator_the_crates_shadow_stays_held(detector):
    # anna looks and accepts the crate by her own signed request while the person crouches
    # behind it (since 7 s): the crate no longer holds the cell by itself, its shadow does
    faults: list[set[str]] = []
    states, inside, outcomes, alerts = run(detector, crate_scene(), accept_at=9.0,
                                           faults=faults)
    accepted = [a for a in alerts if a.kind == "object_accepted"]
    assert len(accepted) == 1 and accepted[0].details["operator"] == "anna"
    assert accepted[0].details["camera"] == "cam0"
    assert accepted[0].details["zone"] == "robot-protective"
    assert "robot-protective" in accepted[0].message and " at x 0." in accepted[0].message
    (obj,) = accepted[0].details["objects"]
    assert obj["accepted_by"] == "anna" and 0.0 < obj["floor_m"][0] < 1.0
    at = round(9.0 * FPS)
    assert OBJECT_IN_ZONE in faults[at - 1] and OBJECT_IN_ZONE not in faults[at + 1]
    # the person still crouches behind it: STOP, no reset accepted
    assert all(s == STOP for s, i in zip(states, inside, strict=True) if i)
    assert not any(o for o, i in zip(outcomes, inside, strict=True) if i)
    assert all(s == STOP for s in states[at:])


def test_a_confirm_clear_reset_does_not_accept_the_crate(detector):
    faults: list[set[str]] = []
    _, _, _, alerts = run(detector, crate_scene(), confirm_at=9.0, faults=faults)
    assert not [a for a in alerts if a.kind.startswith("object_accept")]
    assert OBJECT_IN_ZONE in faults[-1]  # still holds the cell: only its own request accepts


def test_the_refusal_names_the_command_that_accepts_the_object(detector):
    refusals = [m for m in reset_messages(detector, crate_scene()) if "object" in m]
    assert refusals
    assert "monitor objects accept --camera cam0 --zone robot-protective" in refusals[-1]
    # the person lost behind it: a confirm-clear would keep that hold, and the refusal says
    # what ends it (look, accept, then confirm clear)
    assert "that nobody accepted: a confirm-clear keeps that hold" in refusals[-1]


def _crate_then_person() -> sc.Scenario:
    """The crate stands alone at first; accepted at 4.5 s, resets are accepted again (the
    crate alone holds nothing). At 7 s a person walks in behind it and crouches (8-11 s),
    then stands up and walks out in clear view."""
    crate = dataclasses.replace(crate_scene().scene.blocks[0])
    walker = Walker(((0.0, 2.6, -0.1), (7.0, 2.6, -0.1), (8.0, 0.5, -0.1), (11.0, 0.5, -0.1),
                     (13.0, 3.2, -0.1), (16.0, 3.2, -0.1)), height_m=1.6, appear_s=6.5,
                    poses=((8.2, 11.0, "crouching"),))
    return sc.Scenario("crate-accepted", "", CellScene((walker,), (crate,), fps=FPS,
                                                        duration_s=16.0),
                       unobserved_ok=True, check_false_stops=False)


def test_an_accepted_crate_holds_a_person_behind_it_until_seen_free(detector):
    scenario = _crate_then_person()
    states, inside, outcomes, _ = run(detector, scenario, accept_at=4.5)
    t = [k / FPS for k in range(len(states))]
    # accepted, the crate alone no longer holds the cell: a reset is accepted before 6.5 s
    assert any(o for o, tk in zip(outcomes, t, strict=True) if 4.5 <= tk < 6.5)
    assert any(s != STOP for s, tk in zip(states, t, strict=True) if 4.5 <= tk < 6.5)
    # the person behind it: STOP in every frame inside, no reset accepted there
    assert any(inside)
    assert all(s == STOP for s, i in zip(states, inside, strict=True) if i)
    assert not any(o for o, i in zip(outcomes, inside, strict=True) if i)
    # seen again and walked out in clear view, the person is a stranger to the one lost
    # behind the crate: that hold stays, the crate's shadow never seen (waiting ends nothing)
    assert all(s == STOP and not o for s, o in zip(states[round(11 * FPS):],
                                                    outcomes[round(11 * FPS):], strict=True))
    # an operator who has looked confirms clear: the accepted crate is a declared occluder
    # now, released like a fixture of the zone file (an unaccepted one is not:
    # test_a_confirm_clear_reset_does_not_accept_the_crate)
    _, _, after, _ = run(detector, scenario, accept_at=4.5, confirm_at=14.0)
    assert any(after[round(14 * FPS):])
    # without the acceptance the crate keeps holding the cell (the test above can fail)
    _, _, plain_outcomes, _ = run(detector, scenario)
    assert not any(plain_outcomes[round(4.5 * FPS):])


def _walk_scene(*walkers: Walker, blocks=()) -> sc.Scenario:
    return sc.Scenario("nuisance", "", CellScene(walkers, tuple(blocks), fps=FPS,
                                                 duration_s=8.0), check_false_stops=False)


NUISANCE = {
    # in clear view in the warning zone, 1.3 m outside the protective one
    "warning-walk": lambda: _walk_scene(Walker(((0.0, -2.3, 0.5), (4.0, -2.3, -2.3),
                                                (8.0, 2.3, -2.3)))),
    # standing still 8 s in clear view in the warning zone: a lasting change, but a person
    "warning-stand": lambda: _walk_scene(Walker(((0.0, 0.6, -2.3), (8.0, 0.6, -2.3)))),
    # passing in front of a declared bench in the warning zone
    "in-front-of-a-fixture": lambda: _walk_scene(
        Walker(((0.0, -2.4, -2.2), (8.0, 2.4, -2.2))),
        blocks=(Block("bench", (-1.2, -1.9, 0.0), (1.2, -1.4, 0.9)),)),
}


@pytest.mark.parametrize("name, gain", [("warning-walk", 1.0), ("warning-walk", 0.7),
                                        ("warning-stand", 1.0),
                                        ("in-front-of-a-fixture", 1.0)])
def test_persons_and_a_dimmer_light_are_no_objects(detector, name, gain):
    scenario = NUISANCE[name]()
    states, _, _, alerts = run(detector, scenario, gain=gain)
    assert not [a.message for a in alerts if a.kind in (OBJECT_PLACED, VIEW_CHANGED)]
    plain, _, _, _ = run(detector, scenario, reference=False, gain=gain)
    for state in ("RUN", "SLOW"):  # the time in RUN and SLOW within 5 % of without the check
        assert abs(states.count(state) - plain.count(state)) <= 0.05 * len(states), \
            (state, states, plain)


def test_under_a_light_dimmed_to_x07_the_crate_is_still_found_alone(detector):
    # the lighting fit is what makes the test above meaningful: without it the whole view
    # differs from the reference, one region whose foot is on no zone floor, and the crate
    # inside it is missed (checked by removing the fit)
    states, inside, _, alerts = run(detector, crate_scene(), gain=0.7)
    placed = [a for a in alerts if a.kind == OBJECT_PLACED]
    assert len(placed) == 1 and "robot-protective" in placed[0].details["zones"], \
        [a.message for a in alerts]
    x1, y1, x2, y2 = placed[0].details["box_px"]
    assert x2 - x1 < 160 and y2 - y1 < 160  # the crate, not the whole view
    assert all(s == STOP for s, i in zip(states, inside, strict=True) if i)


def _inverted(img: np.ndarray) -> np.ndarray:
    """Every colour turned (no gain and offset of the reference explains it): the crate merges
    with the rest of what changed into one region whose foot is in the warning zone."""
    return 255 - img


# a patterned cover over the cell (8 px squares, +-70 grey levels): most of the zones' image
# differs from the reference however the lighting is fitted
_COVER = np.kron(np.random.default_rng(1).choice([-70.0, 70.0], (45, 80)),
                 np.ones((8, 8)))[:, :, None]


def _covered(img: np.ndarray) -> np.ndarray:
    return np.clip(img.astype(np.float32) + _COVER[:img.shape[0], :img.shape[1]], 0,
                   255).astype(np.uint8)


def test_a_crate_merged_into_a_larger_change_still_holds_the_protective_zone(detector):
    # the merged region's foot is in the warning zone, but it covers the protective zone's
    # floor: judged by the bottom centre alone it was a warning-zone object and the cell ran
    # with the person crouching behind the crate (RUN in all 30 frames they were inside)
    states, inside, accepted, alerts = run(detector, crate_scene(), light=_inverted)
    placed = [a for a in alerts if a.kind == OBJECT_PLACED]
    assert any("robot-protective" in a.details["zones"] for a in placed), \
        [a.message for a in alerts]
    assert all(s == STOP for s, i in zip(states, inside, strict=True) if i)
    assert not any(a for a, i in zip(accepted, inside, strict=True) if i)


def test_a_crate_in_front_of_the_protective_zone_hides_it(detector):
    # it stands in the warning zone, between the camera and the protective zone, and covers
    # the protective floor's image: a person crouching behind it would be inside unseen
    trolley = Block("trolley", (-0.4, -1.75, 0.0), (0.4, -1.35, 1.2), (60, 80, 150),
                    occluder=False, after_reference=True)
    scenario = _walk_scene(Walker(((0.0, 3.5, 2.6), (8.0, 3.5, 2.6))), blocks=(trolley,))
    faults: list[set[str]] = []
    _, _, _, alerts = run(detector, scenario, faults=faults)
    placed = [a for a in alerts if a.kind == OBJECT_PLACED]
    assert placed and all("robot-protective" in a.details["zones"] for a in placed), \
        [a.message for a in alerts]
    assert OBJECT_IN_ZONE in faults[-1]


def test_a_view_changed_for_good_is_a_stop_fault(detector):
    faults: list[set[str]] = []
    states, _, accepted, alerts = run(detector, crate_scene(), faults=faults,
                                           light=_covered)
    changed = [a for a in alerts if a.kind == VIEW_CHANGED]
    assert changed and changed[0].severity == "warning", [a.message for a in alerts]
    first = next(k for k, f in enumerate(faults) if VIEW_CHANGED in f)
    assert first <= 4 * FPS  # the lasting time (3 s) and a frame
    assert all(VIEW_CHANGED in f for f in faults[first:])
    assert all(s == STOP for s in states[first:]), states[first:]
    assert not any(accepted[first:])


def test_a_dimmer_light_is_no_view_change(detector):
    faults: list[set[str]] = []
    _, _, _, alerts = run(detector, crate_scene(), gain=0.7, faults=faults)
    assert not [a for a in alerts if a.kind == VIEW_CHANGED]
    assert not any(VIEW_CHANGED in f for f in faults)


def test_the_object_check_says_nothing_without_a_reference(detector):
    cell = parse_cell(crate_scene().zone_data())
    pipe = Pipeline(detector, "cam0", PolicyConfig(), cell)
    assert pipe.objects == {}
    with_ref = Pipeline(detector, "cam0", PolicyConfig(), cell,
                        references={"cam0": crate_scene().scene.reference()})
    assert set(with_ref.objects) == {"cam0"}
    assert dataclasses.is_dataclass(with_ref.objects["cam0"])


@pytest.mark.slow
def test_the_demo_walk_with_its_first_frame_as_reference_raises_no_object_alert(detector):
    # the robot arm moves in the protective zone's image region: its column is left out
    from monitor.config import demo_cell_path
    from monitor.scene import DemoScene
    from monitor.zones import load_cell

    scene = DemoScene(fps=5.0)
    cell = load_cell(demo_cell_path())
    first, truth = next(iter(scene.frames()))
    assert not truth.persons

    def walk(references):
        pipe = Pipeline(detector, "cam0", PolicyConfig(), cell, references=references)
        states, alerts = [], []
        for img, t in scene.frames():
            res = pipe.process(img, FrameInfo("cam0", t.index, t.time_s, 1280, 720), t.time_s)
            states.append(res.command.state)
            alerts += [a for a in res.alerts if a.kind.startswith("object")]
        return states, alerts

    states, alerts = walk({"cam0": first})
    plain, _ = walk(None)
    assert not alerts, [a.message for a in alerts]
    for state in ("RUN", "SLOW"):
        assert abs(states.count(state) - plain.count(state)) <= 0.05 * len(states)


def test_a_zone_apply_judges_a_standing_crate_against_the_new_zones(detector):
    # the crate stands beside a protective zone drawn to its left; a zone apply brings the
    # zone over it: the object watch follows the new zones at the next frame (before: it kept
    # the old zones' regions, the crate stayed a warning-zone object and never held the cell)
    scenario = crate_scene()
    data = scenario.zone_data()
    back = copy.deepcopy(data)
    (prot,) = [z for z in back["zones"] if z["id"] == "robot-protective"]
    prot["max_m"] = [-0.2, 1.0, 2.2]
    cam = scenario.scene.camera
    refs = {cam.camera_id: scenario.scene.reference()}
    pipe = Pipeline(detector, cam.camera_id, PolicyConfig(), parse_cell(back), references=refs)
    swap_at, found = 5.0, []
    swapped = None
    for k, (img, truth) in enumerate(scenario.scene.frames()):
        t = truth.time_s
        if t >= 7.0:
            break
        if swapped is None and t + 1e-9 >= swap_at:
            assert not any(o.protective for o in pipe.objects["cam0"].objects.values())
            pipe.swap_cell(parse_cell(data))
            swapped = k
        res = pipe.process(img, FrameInfo(cam.camera_id, k, t, cam.width, cam.height), t)
        if swapped is not None:
            found.append(OBJECT_IN_ZONE in {f.name for f in res.faults})
    assert found and found[0], found  # at the first frame on the new zones
    assert all(found)
