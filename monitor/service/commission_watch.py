"""The running monitor's commissioned state, kept current without a restart.

A thread (never the safety loop: hashing a reference image must not delay a decision) looks at
the record beside the config and at every fingerprinted file once a ``period_s``: when any of
them changed (size, mtime or inode), or ``FULL_EVERY_S`` passed, it takes the fingerprint again
and publishes the ``commissioned`` status field when it differs. So a new signed record is in
force, and a changed operators file, key, selectors file or reference image shows as "not
commissioned" naming it, within seconds. A signed zone apply calls ``zones_changed``.

The running model is fingerprinted once, at start: it is the model that was loaded, whatever
the file on disk becomes (a replaced file is in force at the next start, and is seen then).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from pathlib import Path

from monitor.config import MonitorConfig
from monitor.detector.envelope import file_sha256
from monitor.service.commissioned import fingerprint, record_path, safety_files, status_of

FULL_EVERY_S = 30.0  # a rewrite that kept size and mtime (touch -r) is seen by then


def _stamp(path: Path) -> tuple | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_size, st.st_mtime_ns, st.st_ino)


class CommissionWatch:
    """Publishes ``commissioned`` (via ``publish``) at start and whenever it changes."""

    def __init__(self, config_path: str | Path | None, config: MonitorConfig, cell,
                 model_path: str | Path, zones_hash: str,
                 publish: Callable[[dict], None], period_s: float = 1.0) -> None:
        self.config_path, self.config, self.cell = config_path, config, cell
        self.model_path = model_path
        self.model_sha256 = file_sha256(Path(model_path))
        self.zones_hash = zones_hash
        self.publish = publish
        self.period_s = period_s
        self._stop = threading.Event()
        self._dirty = threading.Event()
        self._thread: threading.Thread | None = None
        self._stamps: tuple | None = None
        self.last: dict | None = None
        self.check()

    def zones_changed(self, cell) -> None:
        """A signed zone apply is in force: compare again (on the watch's thread)."""
        self.cell, self.zones_hash = cell, cell.config_hash
        self._dirty.set()

    def check(self) -> dict:
        """Take the fingerprint, compare it with the record, publish when it changed."""
        running = fingerprint(self.config, self.zones_hash, self.model_path, self.cell,
                              self.model_sha256)
        status = status_of(self.config_path, running, self.config)
        if status != self.last:
            self.last = status
            self.publish(status)
        return status

    def _watched(self) -> list[Path]:
        files = list(safety_files(self.config, self.cell, self.model_path).values())
        if self.config_path is not None:
            files.append(record_path(self.config_path))
        return files

    def start(self) -> CommissionWatch:
        self._stamps = tuple(_stamp(p) for p in self._watched())
        self._thread = threading.Thread(target=self._loop, name="commission-watch",
                                        daemon=True)
        self._thread.start()
        return self

    def _loop(self) -> None:
        since_full = 0.0
        while not self._stop.wait(self.period_s):
            since_full += self.period_s
            try:
                stamps = tuple(_stamp(p) for p in self._watched())
                if stamps != self._stamps or self._dirty.is_set() \
                        or since_full >= FULL_EVERY_S:
                    self._stamps, since_full = stamps, 0.0
                    self._dirty.clear()
                    self.check()
            except Exception as exc:  # never a silent end with "yes" left standing
                self._stamps = None  # check again at the next period
                failed = {"checksum": None, "matches": False,
                          "reason": f"the commissioned state cannot be checked: {exc}"}
                if failed != self.last:
                    self.last = failed
                    self.publish(failed)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
