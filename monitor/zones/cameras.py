"""Which camera a command means: one rule for ``--camera`` in every command.

A file (zone file or monitor.toml) with one camera: that camera, ``--camera`` optional. With
several: ``--camera`` is required, and the error lists the choices. A camera that is not in the
file is refused with the file's cameras and how to add one. Never a silent default, never an
internal name.
"""

from __future__ import annotations

from collections.abc import Iterable

from monitor.errors import ConfigError


def choose_camera(cameras: Iterable[str], given: str | None, label: str,
                  add_hint: str = "") -> str:
    """The camera a command works on: ``given`` when it is one of ``cameras``, else the only
    one; a one-line ConfigError otherwise. ``label`` names the file; ``add_hint`` says how to
    add a camera (shown when ``given`` is not in the file)."""
    ids = list(cameras)
    if given is not None:
        if given in ids:
            return given
        hint = f"; {add_hint}" if add_hint else ""
        known = ", ".join(ids) if ids else "none"
        raise ConfigError(f"{label}: unknown camera '{given}' (cameras: {known}){hint}")
    if len(ids) == 1:
        return ids[0]
    if not ids:
        raise ConfigError(f"{label}: has no camera{'; ' + add_hint if add_hint else ''}")
    raise ConfigError(f"{label}: has {len(ids)} cameras: say which with --camera "
                      f"(one of: {', '.join(ids)})")


def zone_file_hint(path: object, camera: str) -> str:
    """How to add a camera to a zone file."""
    return f"add it with 'monitor zones camera add {path} {camera} --size WxH'"
