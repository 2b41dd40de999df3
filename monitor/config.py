"""The service config (TOML): validated before anything starts; one-line errors.

One schema (monitor/schema.py): ``MonitorConfig`` is the root, and each section is the frozen
pydantic dataclass of its stage (``[policy]`` -> PolicyConfig, ``[health]`` -> HealthConfig,
``[bus]`` -> BusConfig, ``[detector]`` -> DetectorConfig, ``[alerts]`` -> AlertLimits,
``[tracker_clock]`` -> TrackerClockConfig, ``[tracker]`` -> TrackerConfig, ``[recorder]`` ->
RecorderConfig, ``[reaction]`` -> ReactionConfig, ``[preview]`` -> PreviewConfig, and the
camera, model, zones and service sections here). Unknown sections and keys are refused, types
and bounds are in the fields' annotations, cross-field rules are validators, and path fields
resolve against the config file's folder. Validation has no side effects: nothing is opened,
downloaded or built.
"""

from __future__ import annotations

import tomllib
from dataclasses import field
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BeforeValidator,
    Field,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    model_validator,
)

from monitor.bus.preview import PreviewConfig
from monitor.bus.session import BusConfig
from monitor.detector import DetectorConfig
from monitor.errors import ConfigError
from monitor.geometry.reaction import ReactionConfig
from monitor.health import HealthConfig
from monitor.incidents.settings import RecorderConfig
from monitor.policy import PolicyConfig
from monitor.pose.tracker_noise import TrackerConfig
from monitor.pose.tracker_time import TrackerClockConfig
from monitor.schema import Bool, ConfigPath, Float, Int, Text, describe, section
from monitor.tracking.cell_persons import CellPersonsConfig
from monitor.tracking.handover import HandoverConfig
from monitor.wire.alerts import AlertLimits

DEMO_SOURCE = "synthetic:demo"
DEMO_LISTEN = ("tcp/127.0.0.1:7447",)


def _camera_index(value: Any) -> Any:
    """TOML ``source = 0`` (a camera index) is the string "0"."""
    return str(value) if isinstance(value, int) and not isinstance(value, bool) else value


def _video_path(value: str, info: ValidationInfo) -> str:
    """A file or image source is a path (relative to the config file); "0", rtsp:// and
    synthetic:demo are not."""
    from monitor.frames import source_kind

    base = (info.context or {}).get("base")
    if base is not None and source_kind(value) in ("file", "image") \
            and not Path(value).is_absolute():
        return str(Path(base) / value)
    return value


@section("camera")
class CameraConfig:
    id: Text = "cam0"
    # camera index ("0"), file, rtsp:// / http:// URL, synthetic:demo
    source: Annotated[Text, BeforeValidator(_camera_index), AfterValidator(_video_path)] = \
        DEMO_SOURCE
    reference: ConfigPath = None  # commissioning image for the "moved" and defocus checks
    realtime: Bool = True  # pace files and synthetic scenes at their frame rate
    loop: Bool = True  # loop files and synthetic scenes (a service runs until stopped)
    # process this camera at most this often (frames a second); None: as fast as frames come.
    # Its newest processed frame is then up to 1/max_fps old: the start-up capacity check
    # refuses a rate too low for [policy] max_frame_age, and rates the host cannot process.
    max_fps: Annotated[Float, Field(gt=0, le=1000)] | None = None


@section("model")
class ModelConfig:
    path: ConfigPath = None  # None: the synthetic model (built on first use)
    # The synthetic model detects only the demo's test figures: on a live camera or stream it is
    # refused unless this says the bench is meant (then log, status and commands say so).
    allow_test_model: Bool = False


@section("zones")
class ZonesConfig:
    file: ConfigPath = None  # None: the demo cell with the demo source, else no zones
    # A cell without an enabled protective zone (or without a zone file) can never STOP for a
    # person: the monitor refuses to start unless this says it is meant (then it says so).
    allow_no_protective: Bool = False


@section("service")
class ServiceConfig:
    # Prometheus endpoint on 127.0.0.1; 0 = off
    metrics_port: Annotated[Int, Field(ge=0, le=65535)] = 0
    metrics_host: Text = "127.0.0.1"
    log_json: Bool = False
    # policy timers are evaluated at least this often without frames
    tick_s: Annotated[Float, Field(gt=0, le=1.0)] = 0.05
    # At start the detector is timed on each camera's frame size and compared with the policy's
    # and the bus's limits (monitor/service/capacity.py): "refuse" a host that cannot watch the cell
    # in time, "warn" only, or "off".
    capacity_check: Literal["refuse", "warn", "off"] = "refuse"
    # "<commissioner> ed25519:<base64>" per line (the operators file's format): whose signed
    # commissioned.json the monitor accepts (docs/commissioning.md). None: no record is
    # accepted, the status says "commissioned: NO". A commissioner's key signs evidence only,
    # never a reset: keep it out of the operators file.
    commissioners_file: ConfigPath = None


def _cameras(value: Any) -> Any:
    """``[camera]`` (one table) or ``[[camera]]`` (an array of tables)."""
    return [value] if isinstance(value, dict) else value


SECTIONS = ("camera", "model", "zones", "detector", "policy", "tracker_clock", "tracker",
            "tracking",
            "health", "bus", "alerts", "service", "recorder", "reaction", "handover", "preview")


@section("config", keys=SECTIONS)
class MonitorConfig:
    # ``[camera]`` for one camera, ``[[camera]]`` (an array of tables) for several
    cameras: Annotated[tuple[CameraConfig, ...], BeforeValidator(_cameras),
                       Field(min_length=1)] = (CameraConfig(),)
    model: ModelConfig = field(default_factory=ModelConfig)
    zones: ZonesConfig = field(default_factory=ZonesConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    tracker_clock: TrackerClockConfig = field(default_factory=TrackerClockConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    tracking: CellPersonsConfig = field(default_factory=CellPersonsConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    bus: BusConfig = field(default_factory=lambda: BusConfig(listen=DEMO_LISTEN))
    alerts: AlertLimits = field(default_factory=AlertLimits)
    service: ServiceConfig = field(default_factory=ServiceConfig)
    recorder: RecorderConfig = field(default_factory=RecorderConfig)
    reaction: ReactionConfig = field(default_factory=ReactionConfig)
    handover: HandoverConfig = field(default_factory=HandoverConfig)
    preview: PreviewConfig = field(default_factory=PreviewConfig)
    source_file: Text | None = None

    @model_validator(mode="after")
    def _unique_cameras(self) -> MonitorConfig:
        ids = [c.id for c in self.cameras]
        dup = next((i for i in ids if ids.count(i) > 1), None)
        if dup is not None:
            raise ValueError(f"camera id {dup!r} is given twice")
        peers = self.handover.peers
        if peers and (not self.bus.role or not self.bus.signing_key or self.bus.role in peers):
            raise ValueError("handover.peers: needs [bus] role and signing_key, and names the "
                             "other monitors of the cell (not this one's role)")
        return self

    @property
    def camera(self) -> CameraConfig:
        """The first (or only) camera."""
        return self.cameras[0]


_CLASSES = {"camera": CameraConfig, "model": ModelConfig, "zones": ZonesConfig,
            "detector": DetectorConfig, "policy": PolicyConfig,
            "tracker_clock": TrackerClockConfig, "tracker": TrackerConfig,
            "tracking": CellPersonsConfig,
            "health": HealthConfig,
            "bus": BusConfig, "alerts": AlertLimits, "service": ServiceConfig,
            "recorder": RecorderConfig, "reaction": ReactionConfig, "handover": HandoverConfig,
            "preview": PreviewConfig}


def _where_in_file(loc: tuple) -> tuple[str, tuple]:
    """(section, key path) of an error location in the whole config."""
    if not loc:
        return "config", ()
    head, rest = str(loc[0]), tuple(loc[1:])
    if head == "cameras":  # the file's [camera] / [[camera]]
        head = "camera"
    if head == "camera" and rest and isinstance(rest[0], int):
        rest = rest[1:]  # which [[camera]] table: its id names it in the message already
    return head, rest


def parse_config(data: dict, where: str = "config", base: Path | None = None) -> MonitorConfig:
    """Validate a parsed TOML document against the one schema. ``base``: the folder relative
    file paths are taken from (the config file's)."""
    unknown = sorted(set(data) - set(SECTIONS))
    if unknown:
        raise ConfigError(f"{where}: unknown section [{unknown[0]}] "
                          f"(known: {', '.join(sorted(SECTIONS))})")
    for name, value in data.items():
        tables = value if name == "camera" and isinstance(value, list) else [value]
        if not all(isinstance(t, dict) for t in tables):
            raise ConfigError(f"{where}: [{name}] must be a table")
    if data.get("camera") == []:
        raise ConfigError(f"{where}: [[camera]] is empty; name at least one camera")
    data = {**data}
    if "camera" in data:
        data["cameras"] = data.pop("camera")
    data.setdefault("bus", {"listen": list(DEMO_LISTEN)})
    try:
        config = _ADAPTER.validate_python({**data, "source_file": where},
                                          context={"base": base})
    except ValidationError as exc:
        raise ConfigError(describe(exc, "config", where, _where_in_file)) from None
    return config


def load_config(path: str | Path | None) -> MonitorConfig:
    """Read and validate a monitor.toml; None gives the embedded demo defaults.

    The embedded demo listens on 127.0.0.1 only and, having no operators file, accepts
    unsigned resets (so `monitor reset --operator you` works beside it); a config file never
    does unless it says ``allow_unsigned_resets = true``."""
    if path is None:
        return MonitorConfig(bus=BusConfig(listen=DEMO_LISTEN, allow_unsigned_resets=True))
    path = Path(path)
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
    return parse_config(data, str(path), path.parent)


_ADAPTER = TypeAdapter(MonitorConfig)


def demo_cell_path() -> Path:
    """The example cell that matches the demo scene, shipped inside the package (package data
    ``monitor/data/demo-cell.yaml``; in the source tree a link to zones/demo-cell.yaml), so the
    demo and the default service also work from an installed wheel."""
    from importlib.resources import files

    resource = files("monitor.data").joinpath("demo-cell.yaml")
    path = Path(str(resource))
    if not path.is_file():
        raise ConfigError("the demo zone file is missing from this installation; reinstall "
                          "workcell-monitor or pass a zone file explicitly")
    return path
