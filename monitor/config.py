"""The service config (TOML): validated before anything starts; one-line errors.

Each section maps onto the frozen dataclass of its stage (``[policy]`` -> PolicyConfig,
``[health]`` -> HealthConfig, ``[bus]`` -> BusConfig, ``[detector]`` -> DetectorConfig,
``[alerts]`` -> AlertLimits). Unknown sections and keys are refused, types are checked by
pydantic, and the stages' own bounds checks run at load time. Validation has no side effects:
nothing is opened, downloaded or built.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import TypeAdapter, ValidationError

from monitor.alerts import AlertLimits
from monitor.bus import BusConfig
from monitor.detector import DetectorConfig
from monitor.errors import ConfigError
from monitor.health import HealthConfig
from monitor.policy import PolicyConfig

DEMO_SOURCE = "synthetic:demo"
DEMO_LISTEN = ("tcp/127.0.0.1:7447",)


@dataclass(frozen=True)
class CameraConfig:
    id: str = "cam0"
    source: str = DEMO_SOURCE  # camera index ("0"), file, rtsp:// / http:// URL, synthetic:demo
    reference: str | None = None  # commissioning image for the "moved" and defocus checks
    realtime: bool = True  # pace files and synthetic scenes at their frame rate
    loop: bool = True  # loop files and synthetic scenes (a service runs until stopped)


@dataclass(frozen=True)
class ModelConfig:
    path: str | None = None  # None: the synthetic model (built on first use)


@dataclass(frozen=True)
class ZonesConfig:
    file: str | None = None  # None: the demo cell with the demo source, else no zones
    # A cell without an enabled protective zone (or without a zone file) can never STOP for a
    # person: the monitor refuses to start unless this says it is meant (then it says so).
    allow_no_protective: bool = False


@dataclass(frozen=True)
class ServiceConfig:
    metrics_port: int = 0  # Prometheus endpoint on 127.0.0.1; 0 = off
    metrics_host: str = "127.0.0.1"
    log_json: bool = False
    tick_s: float = 0.05  # policy timers are evaluated at least this often without frames

    def __post_init__(self) -> None:
        if not 0 <= self.metrics_port <= 65535:
            raise ConfigError(f"service.metrics_port: {self.metrics_port} is not a port "
                              f"(0 = off, 1..65535)")
        if not (math.isfinite(self.tick_s) and 0 < self.tick_s <= 1.0):
            raise ConfigError(f"service.tick_s: must be within (0, 1] seconds, got {self.tick_s}")


@dataclass(frozen=True)
class MonitorConfig:
    # ``[camera]`` for one camera, ``[[camera]]`` (an array of tables) for several
    cameras: tuple[CameraConfig, ...] = (CameraConfig(),)
    model: ModelConfig = field(default_factory=ModelConfig)
    zones: ZonesConfig = field(default_factory=ZonesConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    bus: BusConfig = field(default_factory=lambda: BusConfig(listen=DEMO_LISTEN))
    alerts: AlertLimits = field(default_factory=AlertLimits)
    service: ServiceConfig = field(default_factory=ServiceConfig)
    source_file: str | None = None

    @property
    def camera(self) -> CameraConfig:
        """The first (or only) camera."""
        return self.cameras[0]


_TYPES = {"camera": CameraConfig, "model": ModelConfig, "zones": ZonesConfig,
          "detector": DetectorConfig, "policy": PolicyConfig, "health": HealthConfig,
          "bus": BusConfig, "alerts": AlertLimits, "service": ServiceConfig}


def build_section(name: str, data: Any, where: str) -> Any:
    """One section's dataclass from a TOML table; ConfigError names the file, section and key."""
    cls = _TYPES[name]
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: [{name}] must be a table")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"{where}: [{name}] unknown key {unknown[0]!r} "
                          f"(known: {', '.join(sorted(known))})")
    if name == "camera" and isinstance(data.get("source"), int) \
            and not isinstance(data["source"], bool):
        data = {**data, "source": str(data["source"])}
    # Strict per field: TOML has real types, so "1" or true where seconds are expected is a
    # mistake, not something to coerce. Integers still pass as floats, arrays as tuples.
    hints = typing.get_type_hints(cls)
    values = {}
    for key, value in data.items():
        try:
            values[key] = TypeAdapter(hints[key]).validate_python(_tuples(value), strict=True)
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = ".".join(str(p) for p in (key, *err["loc"]))
            msg = err["msg"].replace("a valid tuple", "an array")
            raise ConfigError(f"{where}: [{name}] {loc}: {msg} (got {_toml_type(value)})"
                              ) from None
    try:
        return cls(**values)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _tuples(value: Any) -> Any:
    """TOML arrays (lists) as tuples, for the frozen dataclasses' tuple fields."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def _toml_type(value: Any) -> str:
    """The TOML name of a value's type (never the value: it may be a password)."""
    for kind, label in ((bool, "a boolean"), (int, "an integer"), (float, "a float"),
                        (str, "a string"), (list, "an array"), (dict, "a table")):
        if isinstance(value, kind):
            return label
    return type(value).__name__


def parse_config(data: dict, where: str = "config") -> MonitorConfig:
    unknown = sorted(set(data) - set(_TYPES))
    if unknown:
        raise ConfigError(f"{where}: unknown section [{unknown[0]}] "
                          f"(known: {', '.join(sorted(_TYPES))})")
    sections = {name: build_section(name, data[name], where) for name in data
                if name != "camera"}
    if "bus" not in sections:
        sections["bus"] = BusConfig(listen=DEMO_LISTEN)
    if "camera" in data:
        tables = data["camera"] if isinstance(data["camera"], list) else [data["camera"]]
        if not tables:
            raise ConfigError(f"{where}: [[camera]] is empty; name at least one camera")
        cameras = tuple(build_section("camera", t, where) for t in tables)
        ids = [c.id for c in cameras]
        dup = next((i for i in ids if ids.count(i) > 1), None)
        if dup is not None:
            raise ConfigError(f"{where}: camera id {dup!r} is given twice")
        sections["cameras"] = cameras
    return MonitorConfig(**sections, source_file=where)


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
    return resolve_paths(parse_config(data, str(path)), path.parent)


def resolve_paths(config: MonitorConfig, base: Path) -> MonitorConfig:
    """Relative file paths in a config file are relative to that file, not to the working
    directory (a service started by systemd has another one than the person who tested it)."""
    from monitor.frames import source_kind

    def fix(value: str | None) -> str | None:
        return str(base / value) if value and not Path(value).is_absolute() else value

    def fix_camera(camera: CameraConfig) -> CameraConfig:
        if source_kind(camera.source) in ("file", "image"):
            camera = dataclasses.replace(camera, source=fix(camera.source))
        return dataclasses.replace(camera, reference=fix(camera.reference))

    bus = dataclasses.replace(config.bus, zenoh_config_file=fix(config.bus.zenoh_config_file),
                              tls_root_ca=fix(config.bus.tls_root_ca),
                              tls_cert=fix(config.bus.tls_cert), tls_key=fix(config.bus.tls_key),
                              signing_key=fix(config.bus.signing_key),
                              operators_file=fix(config.bus.operators_file))
    detector = dataclasses.replace(config.detector,
                                   self_test_image=fix(config.detector.self_test_image))
    return dataclasses.replace(
        config, cameras=tuple(fix_camera(c) for c in config.cameras), bus=bus, detector=detector,
        model=ModelConfig(fix(config.model.path)),
        zones=dataclasses.replace(config.zones, file=fix(config.zones.file)))


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
