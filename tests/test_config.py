"""monitor.toml: parsing into the stages' dataclasses, and one-line errors that refuse to start."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from monitor.bus.session import BusConfig
from monitor.config import (
    DEMO_LISTEN,
    DEMO_SOURCE,
    MonitorConfig,
    ServiceConfig,
    demo_cell_path,
    load_config,
    parse_config,
)
from monitor.detector import DetectorConfig
from monitor.errors import ConfigError
from monitor.health import HealthConfig
from monitor.policy import PolicyConfig
from monitor.wire.alerts import AlertLimits
from tests.helpers import assert_one_line

FULL = """\
[camera]
id = "cam1"
source = 0
reference = "ref.png"
realtime = false
loop = false

[model]
path = "/nowhere/model.onnx"

[zones]
file = "/nowhere/cell.yaml"

[detector]
score_threshold = 0.4
threads = 1
anchors = [[10, 14], [23, 27], [37, 58], [81, 82], [135, 169], [344, 319]]

[policy]
clear_time = 2          # an integer where seconds are floats
restart_interlock = "auto"
frame_timeout = 0.4

[health]
lost_after_s = 0.8

[bus]
cell = "c7"
listen = ["tcp/127.0.0.1:7999"]
heartbeat_hz = 20.0
ttl_ms = 200

[alerts]
min_interval = 2.5

[service]
metrics_port = 9108
log_json = true
tick_s = 0.02
"""


def write(tmp_path: Path, text: str, name: str = "monitor.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path



def test_no_config_is_the_embedded_demo():
    config = load_config(None)
    # the embedded demo listens on loopback only, so it takes unsigned resets (a config file
    # never does unless it says so)
    assert config.bus.allow_unsigned_resets and not MonitorConfig().bus.allow_unsigned_resets
    assert dataclasses.replace(config, bus=MonitorConfig().bus) == MonitorConfig()
    assert config.camera.source == DEMO_SOURCE and config.zones.file is None
    assert config.bus.listen == DEMO_LISTEN and config.bus.mode is None  # peer on loopback
    assert config.service.metrics_port == 0  # metrics off by default
    assert demo_cell_path().is_file()


def test_every_section_maps_onto_its_stage_dataclass(tmp_path):
    config = load_config(write(tmp_path, FULL))
    assert config.source_file == str(tmp_path / "monitor.toml")
    assert config.camera.source == "0"  # a camera index given as a TOML integer
    assert (config.camera.id, config.camera.realtime, config.camera.loop) == ("cam1", False, False)
    assert config.model.path == "/nowhere/model.onnx"  # validation opens nothing
    assert config.zones.file == "/nowhere/cell.yaml"
    assert config.detector == DetectorConfig(
        score_threshold=0.4, threads=1,
        anchors=((10, 14), (23, 27), (37, 58), (81, 82), (135, 169), (344, 319)))
    assert config.policy == PolicyConfig(clear_time=2.0, restart_interlock="auto",
                                         frame_timeout=0.4)
    assert isinstance(config.policy.clear_time, float)
    assert config.health == HealthConfig(lost_after_s=0.8)
    assert config.bus.listen == ("tcp/127.0.0.1:7999",)  # TOML array -> tuple
    assert config.bus.key_prefix == "workcell/c7/"
    assert config.alerts == AlertLimits(min_interval=2.5)
    assert config.service == ServiceConfig(metrics_port=9108, log_json=True, tick_s=0.02)


def test_a_config_without_bus_section_listens_on_loopback_only(tmp_path):
    config = load_config(write(tmp_path, "[policy]\nclear_time = 1.5\n"))
    assert config.bus == BusConfig(listen=DEMO_LISTEN, instance=config.bus.instance)
    assert config.policy.clear_time == 1.5 and config.camera.source == DEMO_SOURCE


def test_an_empty_bus_section_keeps_zenoh_defaults(tmp_path):
    config = load_config(write(tmp_path, "[bus]\ncell = \"x\"\n"))
    assert config.bus.listen == ()  # given a [bus] table, nothing is added to it


@pytest.mark.parametrize(("text", "needles"), [
    pytest.param("[camera]\nsourc = \"0\"\n", ["[camera]", "unknown key 'sourc'", "source"],
                 id="unknown-key"),
    pytest.param("[cameras]\nid = \"x\"\n", ["unknown section [cameras]", "camera"],
                 id="unknown-section"),
    pytest.param("camera = 5\n", ["[camera] must be a table"], id="section-not-a-table"),
    pytest.param("[policy]\nclear_time = \"soon\"\n",
                 ["[policy] clear_time", "valid number", "got a string"], id="string-for-number"),
    pytest.param("[policy]\nframe_timeout = true\n",
                 ["[policy] frame_timeout", "valid number", "got a boolean"],
                 id="boolean-for-seconds"),
    pytest.param("[camera]\nloop = \"yes\"\n", ["[camera] loop", "valid boolean", "got a string"],
                 id="string-for-boolean"),
    pytest.param("[detector]\nthreads = 2.5\n", ["[detector] threads", "valid integer"],
                 id="float-for-integer"),
    pytest.param("[bus]\nlisten = \"tcp/127.0.0.1:7447\"\n",
                 ["[bus] listen", "an array", "got a string"], id="string-for-array"),
    pytest.param("[bus]\nlisten = [7447]\n", ["[bus] listen.0", "valid string"],
                 id="array-item-type"),
    pytest.param("[detector]\nanchors = [[10, 14], [23]]\n", ["[detector] anchors.1.1"],
                 id="short-anchor-pair"),
    pytest.param("[camera]\nid = 5\n", ["[camera] id", "valid string"], id="integer-for-string"),
    pytest.param("[policy]\nclear_time = -1\n", ["[policy] clear_time", "greater than 0", "got -1"],
                 id="negative-seconds"),
    pytest.param("[policy]\nrestart_interlock = \"sometimes\"\n",
                 ["[policy] restart_interlock", "'manual' or 'auto'", "got 'sometimes'"],
                 id="bad-choice"),
    pytest.param("[bus]\nheartbeat_hz = 10.0\nttl_ms = 50\n",
                 ["[bus] ttl_ms", "heartbeat period"], id="ttl-below-heartbeat"),
    pytest.param("[bus]\nmode = \"server\"\n", ["[bus] mode", "'server'"], id="bad-zenoh-mode"),
    pytest.param("[service]\nmetrics_port = 99999\n", ["[service] metrics_port", "99999"],
                 id="port-out-of-range"),
    pytest.param("[service]\ntick_s = 0\n", ["[service] tick_s", "greater than 0"], id="zero-tick"),
    pytest.param("[health]\nlost_after_s = -2\n",
                 ["[health] lost_after_s", "greater than or equal to 0"], id="health-bound"),
    pytest.param("[policy\nclear_time = 1\n", ["not valid TOML", "line 1"], id="not-toml"),
])
def test_bad_config_is_one_line_naming_file_section_and_key(tmp_path, text, needles):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert_one_line(err.value, str(path), *needles)


def test_a_wrong_password_type_does_not_print_the_value(tmp_path):
    path = write(tmp_path, "[bus]\nuser = \"monitor\"\npassword = 123456789\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert_one_line(err.value, "[bus] password", "got an integer")
    assert "123456789" not in str(err.value)


def test_missing_and_unreadable_config_files(tmp_path):
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path / "absent.toml")
    assert_one_line(err.value, "absent.toml", "no such config file")
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path)  # a directory
    assert_one_line(err.value, str(tmp_path), "cannot read")


def test_parse_config_names_where_the_data_came_from():
    with pytest.raises(ConfigError) as err:
        parse_config({"policy": {"clear_tme": 1}}, "inline")
    assert_one_line(err.value, "inline: [policy] unknown key 'clear_tme'", "clear_time")


@pytest.mark.parametrize(("source", "expected"), [
    ("video.mp4", "{dir}/video.mp4"), ("0", "0"), ("rtsp://10.0.0.2/s", "rtsp://10.0.0.2/s"),
    ("synthetic:demo", "synthetic:demo"), ("/abs/cam.png", "/abs/cam.png")])
def test_relative_paths_are_relative_to_the_config_file(tmp_path, source, expected):
    (tmp_path / "monitor.toml").write_text(
        f'[camera]\nsource = "{source}"\nreference = "ref.png"\n[zones]\nfile = "cell.yaml"\n'
        '[bus]\nzenoh_config_file = "zenoh/peer.json5"\n')
    config = load_config(tmp_path / "monitor.toml")
    assert config.camera.source == expected.format(dir=tmp_path)
    assert config.zones.file == str(tmp_path / "cell.yaml")
    assert config.camera.reference == str(tmp_path / "ref.png")
    assert config.bus.zenoh_config_file == str(tmp_path / "zenoh" / "peer.json5")


# --- one schema ---------------------------------------------------------------------------------

def _path_fields() -> list[tuple[str, str]]:
    """(section, key) of every field typed ConfigPath, found in the schema itself: a path field
    added later is covered by the next test without anyone listing it."""
    import typing

    from monitor.config import _CLASSES
    from monitor.schema import ConfigPath

    found = []
    for name, cls in _CLASSES.items():
        hints = typing.get_type_hints(cls, include_extras=True)
        found += [(name, key) for key, hint in hints.items() if hint == ConfigPath]
    return found


def test_the_schema_has_the_path_fields_we_know_of():
    assert {("camera", "reference"), ("model", "path"), ("zones", "file"),
            ("detector", "self_test_image"), ("bus", "signing_key"),
            ("bus", "operators_file")} <= set(_path_fields())


@pytest.mark.parametrize(("section", "key"), _path_fields())
def test_every_path_field_is_relative_to_the_config_file(tmp_path, section, key):
    extra = {"detector": 'self_test_box = [1, 2, 30, 40]\n',
             "bus": ""}.get(section, "")
    if (section, key) == ("bus", "tls_cert"):
        extra = 'tls_key = "/abs/k.pem"\n'
    if (section, key) == ("bus", "tls_key"):
        extra = 'tls_cert = "/abs/c.pem"\n'
    (tmp_path / "monitor.toml").write_text(f'[{section}]\n{key} = "sub/file.x"\n{extra}')
    config = load_config(tmp_path / "monitor.toml")
    value = getattr(config.camera if section == "camera" else getattr(config, section), key)
    assert value == str(tmp_path / "sub" / "file.x")
    # built in code there is no config file: the path stays as given
    cls = type(config.camera if section == "camera" else getattr(config, section))
    values = {key: "sub/file.x"}
    if section == "detector":
        values["self_test_box"] = (1.0, 2.0, 30.0, 40.0)
    if key in ("tls_cert", "tls_key"):
        values["tls_key" if key == "tls_cert" else "tls_cert"] = "/abs/x.pem"
    assert getattr(cls(**values), key) == "sub/file.x"


@pytest.mark.parametrize("section", ["camera", "model", "zones", "detector", "policy", "health",
                                     "bus", "alerts", "service"])
def test_every_section_refuses_an_unknown_key_naming_file_section_and_key(tmp_path, section):
    path = write(tmp_path, f"[{section}]\nbogus_key = 1\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert_one_line(err.value, str(path), f"[{section}] unknown key 'bogus_key'", "known: ")


@pytest.mark.parametrize(("cls", "values", "needle"), [
    (PolicyConfig, {"clear_time": 0}, "policy.clear_time"),
    (HealthConfig, {"snapshot_quality": 101}, "health.snapshot_quality"),
    (DetectorConfig, {"top_k": 0}, "detector.top_k"),
    (BusConfig, {"heartbeat_hz": float("inf")}, "bus.heartbeat_hz"),
    (AlertLimits, {"min_interval": -1.0}, "alerts.min_interval"),
    (ServiceConfig, {"tick_s": 2.0}, "service.tick_s"),
])
def test_a_section_built_in_code_follows_the_same_rules_as_the_file(tmp_path, cls, values,
                                                                      needle):
    with pytest.raises(ConfigError) as err:
        cls(**values)
    assert_one_line(err.value, needle)
    section = needle.split(".")[0]
    key, value = next(iter(values.items()))
    toml_value = "inf" if value == float("inf") else value
    path = write(tmp_path, f"[{section}]\n{key} = {toml_value}\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert_one_line(err.value, f"[{section}] {key}")
    # replacing a field re-validates too: a valid config cannot be edited into an invalid one
    with pytest.raises(ConfigError):
        dataclasses.replace(cls(), **values)
