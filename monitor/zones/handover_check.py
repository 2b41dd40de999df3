"""`monitor zones validate --config monitor.toml`: what the zone file means for the hand-over
the config asks for. A person seen only by a camera without a calibration has no floor point,
so with ``[handover] peers`` that camera hands nobody over (docs/consumer.md); today's one
other place that says so is the log of ``monitor run``. The caller loads the config: the
zones layer never imports monitor.config (which sits above every stage)."""

from __future__ import annotations

from monitor.zones.files import Cell


def uncalibrated_handover_lines(cell: Cell, camera_ids: tuple[str, ...],
                                peers: tuple[str, ...]) -> list[str]:
    """One warning per camera (of the zone file or the config) without a calibration, when
    the config names hand-over peers; none without peers."""
    if not peers:
        return []
    cameras = sorted(set(cell.cameras) | set(camera_ids))
    return [f"camera '{cam}' has no calibration: with [handover] peers "
            f"({', '.join(sorted(peers))}) its persons have no floor point and are never "
            f"handed over" for cam in cameras if cam not in cell.camera_models]

