"""Retention: incidents older than ``retention_days`` go, then the oldest while the incidents
take more than ``max_gb`` or the disk has less than ``min_free_gb`` free. Pure of threads: the
recorder's worker calls ``enforce`` after each incident and about once a second."""

from __future__ import annotations

import shutil
from pathlib import Path

GB = 1024 ** 3


class DiskFloor(OSError):
    """Less free space than the floor, and no incident left to delete."""


def free_bytes(path: Path) -> int:
    return shutil.disk_usage(path).free


def enforce(store, retention_days: float, max_gb: float, min_free_gb: float, now_wall: float,
            free=free_bytes) -> int:
    """Delete incidents until the limits hold; the number deleted. Raises ``DiskFloor`` when
    the free space stays below ``min_free_gb`` with nothing left to delete."""
    deleted = 0
    cutoff = now_wall - retention_days * 86400.0
    while (old := store.oldest(before_wall=cutoff)) is not None:
        store.delete(old)
        deleted += 1
    while store.total_bytes() > max_gb * GB and (old := store.oldest()) is not None:
        store.delete(old)
        deleted += 1
    while free(store.data_dir) < min_free_gb * GB:
        old = store.oldest()
        if old is None:
            have = free(store.data_dir) / GB
            raise DiskFloor(f"{store.data_dir}: {have:.2f} GB free, below the floor of "
                            f"min_free_gb = {min_free_gb:g} GB")
        store.delete(old)
        deleted += 1
    return deleted
