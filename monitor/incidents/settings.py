"""``[recorder]``: the incident recorder's settings, and where its data lives.

The recorder is an optional extra beside the safety loop (docs/incidents.md): off by default,
and nothing here can make the monitor command anything else.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Annotated

from pydantic import Field

from monitor.schema import Bool, ConfigPath, Float, Int, section


@section("recorder")
class RecorderConfig:
    enabled: Bool = False
    # where incidents and their index go; None: $WORKCELL_MONITOR_HOME/incidents, else the
    # service's StateDirectory ($STATE_DIRECTORY/incidents), else ~/.local/state/...
    data_dir: ConfigPath = None
    # seconds of video kept before the event, and recorded after it
    pre_s: Annotated[Float, Field(gt=0, le=120)] = 10.0
    post_s: Annotated[Float, Field(gt=0, le=120)] = 5.0
    # frames a second per camera kept in the ring and written into clips (bounds CPU and memory)
    max_fps: Annotated[Float, Field(gt=0, le=60)] = 10.0
    # memory of the pre-event ring, all cameras together (JPEG frames); default: 4 cameras x
    # 10 s x 10 fps of 720p. When full, the oldest frames go first (the pre-event window shrinks)
    memory_mb: Annotated[Float, Field(gt=0, le=4096)] = 96.0
    jpeg_quality: Annotated[Int, Field(ge=30, le=95)] = 75
    retention_days: Annotated[Float, Field(gt=0)] = 30.0
    max_gb: Annotated[Float, Field(gt=0)] = 5.0
    # recording stops (with an alert) rather than leave less free space than this on the disk;
    # the oldest incidents are deleted first to stay above it
    min_free_gb: Annotated[Float, Field(ge=0)] = 1.0
    # how long a write waits for a locked index before recording stops (s)
    sqlite_timeout_s: Annotated[Float, Field(gt=0, le=30)] = 1.0
    # incidents recorded at once (clips being written); more are indexed without a clip
    max_open: Annotated[Int, Field(ge=1, le=64)] = 8


def default_data_dir() -> Path:
    """$WORKCELL_MONITOR_HOME/incidents, else $STATE_DIRECTORY/incidents (systemd's
    StateDirectory), else ~/.local/state/workcell-monitor/incidents."""
    home = os.environ.get("WORKCELL_MONITOR_HOME")
    if home:
        return Path(home) / "incidents"
    state = os.environ.get("STATE_DIRECTORY")
    if state:
        return Path(state.split(":")[0]) / "incidents"
    return Path.home() / ".local" / "state" / "workcell-monitor" / "incidents"


def data_dir_of(config: RecorderConfig) -> Path:
    return Path(config.data_dir) if config.data_dir else default_data_dir()


def config_hash(path: str | Path | None) -> str:
    """sha256 of the config file's bytes ("embedded" for the built-in demo config)."""
    if path is None:
        return "embedded"
    try:
        return "sha256:" + hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return "unreadable"
