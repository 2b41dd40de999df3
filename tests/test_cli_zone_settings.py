"""Mute rules and zone-set switching rules edited with the CLI (`monitor zones mute`,
`monitor zones set rules`) instead of by hand in YAML: what is written is what the monitor
loads, and a bad value is one line that writes nothing."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from monitor import zones as zn
from tests.helpers import one_error_line, zones_cli

DEMO = Path(__file__).resolve().parents[1] / "zones" / "demo-cell.yaml"


@pytest.fixture
def cell_file(tmp_path: Path) -> Path:
    path = tmp_path / "cell.yaml"
    shutil.copy(DEMO, path)
    return path


def zone(path: Path, zone_id: str):
    return next(z for z in zn.load_cell(path).spec.zones if z.id == zone_id)


def test_allowing_a_mute_writes_the_rule_the_monitor_loads(cell_file, capsys):
    assert zone(cell_file, "robot-protective").mute is None
    assert zones_cli("mute", cell_file, "robot-protective", "--operators", "anna, bob",
                     "--max-s", "60", "--speed-scale", "0.2") == 0
    mute = zone(cell_file, "robot-protective").mute
    assert (mute.operators, mute.max_s, mute.as_, mute.speed_scale) == \
        (("anna", "bob"), 60.0, "warning", 0.2)
    assert "may be muted by anna, bob for at most 60 s" in capsys.readouterr().out
    # a later change keeps the rest of the rule
    assert zones_cli("mute", cell_file, "robot-protective", "--as", "none") == 0
    mute = zone(cell_file, "robot-protective").mute
    assert (mute.operators, mute.max_s, mute.as_) == (("anna", "bob"), 60.0, "none")
    assert zones_cli("mute", cell_file, "robot-protective") == 0  # shows it
    assert "checked as nothing" in capsys.readouterr().out


def test_unmutable_and_remove(cell_file, capsys):
    zones_cli("mute", cell_file, "robot-protective", "--operators", "anna", "--max-s", "30")
    assert zones_cli("mute", cell_file, "robot-protective", "--unmutable") == 0
    z = zone(cell_file, "robot-protective")
    assert z.mute is None and z.unmutable is True
    assert zones_cli("mute", cell_file, "robot-protective", "--remove") == 0
    z = zone(cell_file, "robot-protective")
    assert z.mute is None and not z.unmutable
    assert "never muted" in capsys.readouterr().out


@pytest.mark.parametrize("args, needle", [
    (("--operators", "anna"), "give --max-s"),
    (("--operators", "anna", "--max-s", "7200"), "max_s"),
    (("--operators", "anna", "--max-s", "nan"), "max_s"),
    (("--operators", "anna", "--max-s", "10", "--speed-scale", "1.5"), "speed_scale"),
    (("--unmutable", "--remove"), "either"),
], ids=["no-max", "too-long", "nan", "scale", "two-actions"])
def test_a_bad_mute_rule_is_one_line_and_writes_nothing(cell_file, capsys, args, needle):
    before = cell_file.read_bytes()
    assert zones_cli("mute", cell_file, "robot-protective", *args) != 0
    assert needle in one_error_line(capsys)
    assert cell_file.read_bytes() == before


def test_an_unknown_zone_is_one_line(cell_file, capsys):
    assert zones_cli("mute", cell_file, "nowhere", "--unmutable") != 0
    assert "no zone 'nowhere'" in one_error_line(capsys)


@pytest.fixture
def sets_file(cell_file: Path) -> Path:
    assert zones_cli("set", "add", cell_file, "A", "--zones", "robot-protective") == 0
    assert zones_cli("set", "add", cell_file, "B", "--zones", "robot-protective,robot-warning"
                     ) == 0
    return cell_file


def test_switching_rules_are_written_and_loaded(sets_file, capsys):
    assert zones_cli("set", "rules", sets_file, "--allow", "A:B", "--switch-over", "2.5",
                     "--default", "B", "--selector-ttl", "5") == 0
    spec = zn.load_cell(sets_file).spec
    assert (spec.transitions, spec.switch_over_s, spec.default_set, spec.selector_ttl_s) == \
        ((("A", "B"),), 2.5, "B", 5.0)
    assert "transitions A->B; switch-over 2.5 s" in capsys.readouterr().out
    assert zones_cli("set", "rules", sets_file, "--any", "--no-selector-ttl") == 0
    spec = zn.load_cell(sets_file).spec
    assert spec.transitions is None and spec.selector_ttl_s is None
    assert spec.switch_over_s == 2.5  # untouched
    assert zones_cli("set", "rules", sets_file, "--none") == 0
    assert zn.load_cell(sets_file).spec.transitions == ()


@pytest.mark.parametrize("args, needle", [
    (("--allow", "A:C"), "C"),
    (("--allow", "AB"), "FROM:TO"),
    (("--switch-over", "100"), "switch_over_s"),
    (("--default", "Z"), "Z"),
    (("--any", "--none"), "one of"),
], ids=["unknown-set", "no-colon", "long-switch", "unknown-default", "two-modes"])
def test_bad_switching_rules_are_one_line_and_write_nothing(sets_file, capsys, args, needle):
    capsys.readouterr()
    before = sets_file.read_bytes()
    assert zones_cli("set", "rules", sets_file, *args) != 0
    assert needle in one_error_line(capsys)
    assert sets_file.read_bytes() == before
