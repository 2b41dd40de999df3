"""The deployment files parse and agree with the code."""

from __future__ import annotations

import configparser
from pathlib import Path

import pytest
import zenoh

from monitor.config import load_config

DEPLOY = Path(__file__).resolve().parents[1] / "deploy"


def test_example_monitor_toml_is_valid():
    config = load_config(DEPLOY / "monitor.toml")
    assert config.camera.id == "cam0"
    assert config.policy.restart_interlock == "manual"
    assert config.bus.zenoh_config_file.endswith("peer.json5")
    assert config.service.metrics_port == 9108


@pytest.mark.parametrize("name", sorted(p.name for p in (DEPLOY / "zenoh").glob("*.json5")))
def test_zenoh_configs_load(name):
    zenoh.Config.from_file(str(DEPLOY / "zenoh" / name))


def test_systemd_unit_runs_the_service_with_sigterm():
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str
    unit.read(DEPLOY / "workcell-monitor.service")
    assert "monitor run --config" in unit["Service"]["ExecStart"]
    assert unit["Service"]["KillSignal"] == "SIGTERM"
    assert unit["Service"]["Restart"] == "always"
