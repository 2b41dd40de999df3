"""The scenario suite through the real pipeline (synthetic model, zone check, policy, resets).

Every scenario must have: no frame without STOP while ground truth has a person in the
protective zone, no reset accepted then, the STOP no later than the entry, and no STOP for
persons in clear view more than 1 m outside. 5 fps keeps the run short; ``monitor eval
scenarios`` and ``benchmarks/scenarios.py`` run them at 10 fps.
"""

from __future__ import annotations

import dataclasses

import pytest

from monitor.replay import scenarios as sc

FPS = 5.0


def _by_name(name: str) -> sc.Scenario:
    return sc.select([name], FPS)[0]


def _assert_safe(r: sc.ScenarioResult) -> None:
    table = sc.format_table([r])
    assert r.missed_stop_frames == 0, table
    assert r.resets_accepted_inside == 0, table
    if r.entry_s is not None:
        assert r.first_stop_s is not None and r.first_stop_s <= r.entry_s, table
    assert r.false_stop_frames == 0, table


def test_legs_hidden_behind_a_waist_high_bench(detector):
    r = sc.run_scenario(_by_name("bench-1.15"), detector)
    _assert_safe(r)
    assert r.entry_s is not None and r.resets_refused_inside > 0
    assert r.resets_accepted_outside > 0  # the cell is released once the person is out


@pytest.mark.slow
@pytest.mark.parametrize("name", [
    "bench-0.80", "bench-0.95", "bench-1.30", "crate-crouch", "robot-base", "kneeling",
    "running", "clear-view-outside", "two-persons", "masked-cutout", "kneel-edge",
    "platform-0.5",
])
def test_scenario(detector, name):
    r = sc.run_scenario(_by_name(name), detector)
    _assert_safe(r)


@pytest.mark.slow
def test_a_crouching_person_in_clear_view_at_the_zone_edge(detector):
    # head 0.6 m, feet in view: the placement from the head alone put them 0.6 m nearer the
    # camera, outside the zone (23 missed-STOP frames at 10 fps before the feet were kept)
    _assert_safe(sc.run_scenario(_by_name("crouch-open"), detector))


@pytest.mark.slow
def test_a_person_on_a_declared_1_m_platform(detector):
    r = sc.run_scenario(_by_name("platform-1.0"), detector)
    _assert_safe(r)
    assert r.entry_s is not None


@pytest.mark.slow
def test_without_the_platform_declared_the_platform_case_is_missed(detector):
    # the suite can fail: the same scene with the platform left out of the zone file
    s = dataclasses.replace(_by_name("platform-1.0"), declare_floors=False)
    r = sc.run_scenario(s, detector)
    assert r.missed_stop_frames > 0, sc.format_table([r])


@pytest.mark.slow
def test_an_undeclared_bench_is_found_by_the_references_edges_only(detector):
    # the bench left out of the zone file: its top edge in the commissioning reference tells
    # the cut-off box (97 missed-STOP frames at 10 fps before); without the reference the
    # suite can fail
    s = dataclasses.replace(_by_name("bench-1.15"), declare_occluders=False)
    _assert_safe(sc.run_scenario(s, detector))
    # without the reference too, since a box wider than one person is also placed as one
    # person at each end (monitor.pipeline.locate.check_seen): the box cut off at the bench
    # top as the person walks in is that wide, and its end nearest the zone is in it (before:
    # missed STOP frames at the zone's edge; the reference's own part: the bench-inside test
    # below)
    _assert_safe(sc.run_scenario(dataclasses.replace(s, reference=False), detector))


@pytest.mark.parametrize("name", ["bench-inside-undeclared", "bench-inside-declared",
                                  "crouch-behind-bench", "hidden-behind-bench"])
def test_a_person_behind_a_bench_inside_the_zone_is_a_stop_in_every_frame(detector, name):
    # standing behind a 1.15 m bench (about half in view), declared or only in the reference;
    # crouching behind a declared 1 m bench (a sliver of the head in view) or wholly hidden
    # there: before, the undeclared bench gave SLOW and an accepted reset, the crouching
    # persons 22 frames RUN and an accepted reset at 5 fps (the floor behind the bench was
    # "seen" for a standing 1 m person, whose head shows)
    r = sc.run_scenario(_by_name(name), detector)
    _assert_safe(r)
    inside = [s.state for s in r.scores if s.inside]
    assert inside and set(inside) == {"STOP"}, sc.format_table([r])
    assert r.resets_refused_inside > 0


def test_without_the_reference_the_bench_inside_is_missed(detector):
    # the first test above can fail: no reference, the undeclared bench is not seen
    s = dataclasses.replace(_by_name("bench-inside-undeclared"), reference=False)
    r = sc.run_scenario(s, detector)
    assert r.missed_stop_frames > 0 or r.resets_accepted_inside > 0, sc.format_table([r])


@pytest.mark.parametrize("name", ["cabinet-step-1fps", "mask-step-1fps"])
def test_a_person_stepping_out_of_sight_into_the_zone_between_two_frames_at_1_fps(detector,
                                                                                name):
    # seen standing still 0.8 m outside the protective zone, hidden behind a 2 m cabinet
    # inside it in the next frame (1 s later), or in front of a tight-masked cut-out there
    # (the mask suppresses both): without the zones within walking reach of a lost person
    # the warning-zone hold alone gave SLOW in every frame with the person inside
    r = sc.run_scenario(_by_name(name), detector)
    _assert_safe(r)
    assert r.entry_s is not None and r.resets_refused_inside > 0
    inside = [s.state for s in r.scores if s.inside]
    assert inside and set(inside) == {"STOP"}, sc.format_table([r])


@pytest.mark.parametrize("name", ["edge-right-cut", "edge-head-cut"])
def test_a_person_cut_by_the_image_border_inside_the_zone(detector, name):
    # held before this was a test: SLOW while outside, STOP from the entry on
    r = sc.run_scenario(_by_name(name), detector)
    _assert_safe(r)
    assert r.entry_s is not None and "SLOW" in {s.state for s in r.scores if not s.inside}


def test_scoring_counts_a_missed_stop_and_an_accepted_reset():
    frames = (sc.FrameScore(0.0, "RUN", True, False, True),
              sc.FrameScore(0.1, "STOP", True, False, False),
              sc.FrameScore(0.2, "STOP", False, True, None))
    r = sc.ScenarioResult("x", 3, 0.0, None, 1, 1, 1, 1, 0, scores=frames)
    assert not r.ok
    assert "FAIL" in sc.format_table([r])
    good = sc.ScenarioResult("y", 3, 0.5, 0.4, 0, 0, 0, 2, 1)
    assert good.ok and "ok" in sc.format_table([good])
    late = dataclasses.replace(good, first_stop_s=0.6)
    assert not late.ok


def test_unknown_scenario_is_a_config_error():
    from monitor.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown scenario nope"):
        sc.select(["nope"])


def test_eval_cli_lists_scenarios_and_refuses_unknown_ones():
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "monitor", "eval", "scenarios"]
    listed = subprocess.run([*cmd, "--list"], capture_output=True, text=True, timeout=120)
    assert listed.returncode == 0, listed.stderr
    names = [line.split()[0] for line in listed.stdout.splitlines()]
    assert names[:4] == ["bench-0.80", "bench-0.95", "bench-1.15", "bench-1.30"]
    assert "two-persons" in names and "(needs tracker)" in listed.stdout
    bad = subprocess.run([*cmd, "nope"], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines()[-1].startswith(
        "monitor: error: unknown scenario nope (known: bench-0.80")


@pytest.mark.parametrize("name", ["mask-loose-behind", "mask-loose-front",
                                  "mask-tight-behind", "mask-tight-front"])
def test_a_mask_never_hides_the_person_next_to_its_cut_out(detector, name):
    """A mask drawn tight around its cut-out, and one 50 px larger: the person standing right
    behind it or walking in front of it is in STOP from the first frame inside, never SLOW or
    RUN there, and no reset is accepted there (docs/masks.md)."""
    r = sc.run_scenario(_by_name(name), detector)
    _assert_safe(r)
    inside = [s.state for s in r.scores if s.inside]
    assert inside and set(inside) == {"STOP"}, sc.format_table([r])
