"""`monitor zones validate FILE --config monitor.toml`: with [handover] peers, each camera
without a calibration is one warning line (it hands nobody over); silent without peers or when
every camera is calibrated."""

from __future__ import annotations

from pathlib import Path

import pytest

from monitor import cli
from monitor.wire.signing import new_key_pair

DEMO = Path(__file__).resolve().parents[1] / "zones" / "demo-cell.yaml"
UNCALIBRATED = "  - id: cam1\n    width: 1280\n    height: 720\n\nzones:"


def _config(tmp: Path, peers: bool) -> Path:
    new_key_pair(tmp / "monitor-a.key")
    new_key_pair(tmp / "monitor-b.key")
    text = ('[[camera]]\nid = "cam0"\nsource = "a.mp4"\n'
            '[[camera]]\nid = "cam1"\nsource = "b.mp4"\n'
            '[bus]\ncell = "c1"\nrole = "monitor-a"\nsigning_key = "monitor-a.key"\n')
    if peers:
        text += '[handover]\npeers = { "monitor-b" = "monitor-b.key.pub" }\n'
    path = tmp / "monitor.toml"
    path.write_text(text)
    return path


def _zones(tmp: Path, uncalibrated: bool) -> Path:
    text = DEMO.read_text()
    if uncalibrated:
        text = text.replace("\nzones:", "\n" + UNCALIBRATED, 1)
    path = tmp / "cell.yaml"
    path.write_text(text)
    return path


def _validate(zones: Path, config: Path, capsys) -> tuple[int, list[str]]:
    code = cli.main(["zones", "validate", str(zones), "--config", str(config)])
    return code, [line for line in capsys.readouterr().err.splitlines() if "hand" in line]


def test_peers_and_an_uncalibrated_camera_warn_in_one_line(tmp_path, capsys):
    code, lines = _validate(_zones(tmp_path, True), _config(tmp_path, True), capsys)
    assert code == 0
    assert len(lines) == 1, lines
    assert "warning: camera 'cam1' has no calibration" in lines[0]
    assert "monitor-b" in lines[0] and "never handed over" in lines[0]


@pytest.mark.parametrize(("peers", "uncalibrated"), [(False, True), (True, False)])
def test_silent_without_peers_or_when_calibrated(tmp_path, capsys, peers, uncalibrated):
    if not uncalibrated:  # cam1 of the config is then in the zone file, calibrated
        text = DEMO.read_text()
        cam1 = text[text.index("  - id: cam0"):text.index("\nzones:")].replace("cam0", "cam1")
        zones = tmp_path / "cell.yaml"
        zones.write_text(text.replace("\nzones:", "\n" + cam1 + "\nzones:", 1))
    else:
        zones = _zones(tmp_path, True)
    code, lines = _validate(zones, _config(tmp_path, peers), capsys)
    assert code == 0 and lines == []


def test_a_bad_config_is_one_line(tmp_path, capsys):
    bad = tmp_path / "monitor.toml"
    bad.write_text("[handover]\nkeep_s = -1\n")
    code = cli.main(["zones", "validate", str(_zones(tmp_path, True)), "--config", str(bad)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) >= 1 and "keep_s" in err[-1] and "Traceback" not in "".join(err)
