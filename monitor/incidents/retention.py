"""Retention: incidents older than ``retention_days`` go; then, while the incidents take more
than ``max_gb`` or the disk has less than ``min_free_gb`` free, the oldest incidents that are
not safety incidents. Pure of threads: the recorder's worker calls ``enforce`` after each
incident and about once a second.

A safety incident (``SAFETY_CAUSES``: a STOP, a latch, a refused reset) is never deleted to
make room for anything else. Why: anything that makes incidents (alerts, faults, zone edits
through the console) can be provoked in bulk from the cell network, and oldest-first deletion
then erased the STOPs an investigation needs first (issue 31). Only its age removes one
(``retention_days``, the operator's choice). When only safety incidents are left:

- over ``max_gb``: they are kept and recording goes on (``max_gb`` is a quota; the disk floor
  is the limit), and ``Retention.blocked`` says so, for the recorder's ``retention_blocked``
  alert;
- below the ``min_free_gb`` floor: ``DiskFloor`` (the recorder stops recording, with its
  ``recorder_stopped`` alert) rather than delete a STOP: the evidence already recorded is
  worth more than a clip of the next one, and the alert asks a person to export and free space.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

GB = 1024 ** 3
SAFETY_CAUSES = frozenset({"stop", "latch", "reset_refused"})


class DiskFloor(OSError):
    """Less free space than the floor, and no incident left that may be deleted."""


@dataclass(frozen=True)
class Retention:
    """What one ``enforce`` did: ``deleted`` incidents; ``blocked``: why the limits do not
    hold with only safety incidents left (None: they hold)."""

    deleted: int = 0
    blocked: str | None = None


def free_bytes(path: Path) -> int:
    return shutil.disk_usage(path).free


def is_safety(causes) -> bool:
    return bool(SAFETY_CAUSES.intersection(causes))


def enforce(store, retention_days: float, max_gb: float, min_free_gb: float, now_wall: float,
            free=free_bytes) -> Retention:
    """Delete incidents until the limits hold, never a safety incident to make room (see the
    module's docstring). Raises ``DiskFloor`` when the free space stays below ``min_free_gb``
    with only safety incidents left."""
    deleted = 0
    cutoff = now_wall - retention_days * 86400.0
    while (old := store.oldest(before_wall=cutoff)) is not None:
        store.delete(old)
        deleted += 1
    while store.total_bytes() > max_gb * GB \
            and (old := store.oldest(keep=SAFETY_CAUSES)) is not None:
        store.delete(old)
        deleted += 1
    while free(store.data_dir) < min_free_gb * GB:
        old = store.oldest(keep=SAFETY_CAUSES)
        if old is None:
            have = free(store.data_dir) / GB
            kept = store.count(SAFETY_CAUSES)
            raise DiskFloor(f"{store.data_dir}: {have:.2f} GB free, below the floor of "
                            f"min_free_gb = {min_free_gb:g} GB"
                            + (f"; {kept} safety incidents (STOP, latch, refused reset) are "
                               "kept, never deleted to make room: export them and free space"
                               if kept else ""))
        store.delete(old)
        deleted += 1
    total = store.total_bytes()
    if total > max_gb * GB:
        return Retention(deleted, f"incidents take {total / GB:.2f} GB, over max_gb = "
                                  f"{max_gb:g} GB, and only safety incidents (STOP, latch, "
                                  f"refused reset) are left: {store.count(SAFETY_CAUSES)} kept, "
                                  "never deleted to make room; export them and free space, or "
                                  "lower retention_days")
    return Retention(deleted)
