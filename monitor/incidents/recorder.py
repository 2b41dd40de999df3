"""The incident recorder: a driver sink that never blocks the safety loop.

``on_step`` (the safety loop's thread) only appends the step to a bounded queue: a frame is
kept by reference (frames are never written to after they are made), at most ``max_fps`` per
camera, and dropped and counted when ``MAX_QUEUED_FRAMES`` frames wait already; steps without
a frame are small and dropped only past ``MAX_QUEUED_STEPS``. It never waits, never raises.

A worker thread (lower CPU priority) does the rest: JPEG frames into each camera's ring
(``ring.py``), the incident rules (``triggers.py``), annotated H.264 clips from ``pre_s``
before to ``post_s`` after (``clips.py``), the index (``store.py``, the one writer) and
retention (``retention.py``). Any write error (read-only or missing data dir, full disk, a
locked index) stops recording with a ``recorder_stopped`` alert, handed to ``on_alert`` from
the next ``on_step``; the safety loop goes on and decides exactly as without the recorder.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import secrets
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2

from monitor.driver import Step
from monitor.incidents.clips import CODEC, ClipWriter, overlay
from monitor.incidents.retention import enforce
from monitor.incidents.ring import FrameRing, RingFrame, encode_jpeg
from monitor.incidents.settings import RecorderConfig
from monitor.incidents.store import RECORD, IncidentStore
from monitor.incidents.triggers import Triggers
from monitor.records.events import alert_event, command_event, describe
from monitor.timetext import TimeText
from monitor.types import Alert
from monitor.zones import watch_regions
from monitor.zones.draw import ZoneDrawCache

MAX_QUEUED_FRAMES = 16  # ~45 MB of 720p frames waiting for the worker at most
MAX_QUEUED_STEPS = 4096
STOPPED_ALERT = "recorder_stopped"
BLOCKED_ALERT = "retention_blocked"  # over max_gb with only safety incidents left: kept
SCHEMA = "workcell.incident/1"


@dataclass
class _Open:
    """An incident whose clip window has not ended yet."""

    record: dict
    time_s: float
    end_s: float
    dir: Path
    writers: dict[str, ClipWriter] = field(default_factory=dict)


def _r(value: float) -> float:
    return round(float(value), 4)


def _file_name(camera_id: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", camera_id) + ".mp4"


class IncidentRecorder:
    """A ``Sink``. ``on_alert(alert)``: called from ``on_step`` with the recorder's own alerts
    (recording stopped); ``on_incident(causes)``: called by the worker per new incident
    (Prometheus counters). ``lossless`` (replay only): ``on_step`` waits for the worker
    instead of dropping frames, so a replay's clips are complete and repeatable. ``when``:
    the times of the descriptions and the clips' header as text; live, the local wall-clock
    time (``monitor.timetext.wall_iso``: an incident read days later names the moment as the
    log does); None (replay): seconds of the video."""

    def __init__(self, config: RecorderConfig, data_dir: str | Path, cameras: Sequence[str],
                 cell=None, *, cell_id: str = "", config_hash: str = "",
                 on_alert: Callable[[Alert], None] | None = None,
                 on_incident: Callable[[tuple[str, ...]], None] | None = None,
                 lossless: bool = False, wall: Callable[[], float] = time.time,
                 when: TimeText | None = None) -> None:
        self.config = config
        self.data_dir = Path(data_dir)
        self.cell = cell
        self.cell_id = cell_id
        self.zones_hash = cell.config_hash if cell is not None else ""
        self.config_hash = config_hash
        self.on_alert = on_alert
        self.on_incident = on_incident
        self.lossless = lossless
        self.wall = wall
        self.when = when
        budget = int(config.memory_mb * 2 ** 20 / max(1, len(cameras)))
        self.rings = {c: FrameRing(config.pre_s, budget) for c in cameras}
        self._watch: dict[str, list] = {}
        self._queue: deque[tuple[Step, bool]] = deque()
        self._frames_in = 0  # written by on_step only
        self._frames_out = 0  # written by the worker only
        self._last_taken: dict[str, float] = {}
        self._min_interval = 1.0 / config.max_fps
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._alerts: deque[Alert] = deque()
        self.alerts_raised: list[Alert] = []
        self.stopped: str | None = None
        self.by_cause: Counter[str] = Counter()
        self.incidents = 0
        self.dropped_frames = 0
        self.dropped_steps = 0
        self.step_errors = 0
        self._open: list[_Open] = []
        self._history: deque[tuple[float, dict]] = deque()
        self._triggers = Triggers()
        self._store: IncidentStore | None = None
        self._seq = 0
        self._run_id = secrets.token_hex(2)
        self._last_retention = -math.inf
        self._retention_blocked = False
        self._now = 0.0
        self._zone_drawing: dict[str, ZoneDrawCache] = {}  # the worker's, per camera
        self._thread = threading.Thread(target=self._run, name="incident-recorder", daemon=True)
        self._thread.start()

    # --- the safety loop's side: append, never wait, never raise -----------------------------

    def on_step(self, step: Step) -> None:
        try:
            self._deliver_alerts()
            if self.stopped is not None:
                return
            if len(self._queue) >= MAX_QUEUED_STEPS:
                self.dropped_steps += 1
                return
            take = step.frame is not None and self._due(step.frame.info)
            if take and self._frames_in - self._frames_out >= MAX_QUEUED_FRAMES:
                if self.lossless:
                    while self._frames_in - self._frames_out >= MAX_QUEUED_FRAMES \
                            and self._thread.is_alive() and self.stopped is None:
                        time.sleep(0.002)
                else:
                    take = False
                    self.dropped_frames += 1
            self._queue.append((step, take))
            if take:
                self._frames_in += 1
            self._wake.set()
        except Exception:  # the recorder is an extra: its faults never reach the safety loop
            self.step_errors += 1

    def _due(self, info) -> bool:
        last = self._last_taken.get(info.camera_id)
        if last is not None and info.capture_time - last < self._min_interval * 0.999:
            return False
        self._last_taken[info.camera_id] = info.capture_time
        return True

    def zones_changed(self, cell) -> None:
        """A signed zone apply: incidents from now name and draw the new zone set."""
        self.cell = cell
        self.zones_hash = cell.config_hash
        self._watch = {}  # the worker re-derives each camera's watch regions
        # (the zone drawings keep the cell they drew: a new Cell is drawn afresh)

    def close(self, timeout: float | None = 5.0) -> None:
        """Finish every open incident (clips cut at this moment) and stop the worker; waits
        ``timeout`` (None: as long as it takes, for a replay)."""
        self._closing.set()
        self._wake.set()
        self._thread.join(None if self.lossless else timeout)
        self._deliver_alerts()  # one raised after the last step is still said

    def _deliver_alerts(self) -> None:
        while self._alerts:
            alert = self._alerts.popleft()
            if self.on_alert is not None:
                self.on_alert(alert)

    def status(self) -> dict:
        """Counters for the status queryable and Prometheus; safe from any thread."""
        for _ in range(3):  # the worker may grow a dict while it is copied: copy again
            with contextlib.suppress(RuntimeError):
                return self._status()
        return {"recording": self.stopped is None, "stopped": self.stopped}

    def _status(self) -> dict:
        return {"recording": self.stopped is None, "stopped": self.stopped,
                "data_dir": str(self.data_dir), "incidents": self.incidents,
                "by_cause": dict(self.by_cause), "dropped_frames": self.dropped_frames,
                "dropped_steps": self.dropped_steps, "queued": len(self._queue),
                "ring_bytes": sum(r.bytes for r in list(self.rings.values())),
                "ring_frames": sum(len(r) for r in list(self.rings.values()))}

    # --- the worker ----------------------------------------------------------------------------

    def _run(self) -> None:
        with contextlib.suppress(OSError, AttributeError):  # this thread only (Linux)
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
        try:
            self._store = IncidentStore(self.data_dir, self.config.sqlite_timeout_s)
            self._retention(force=True)
        except Exception as exc:
            self._stop(exc)
        while True:
            self._wake.wait(0.2)
            self._wake.clear()
            while self._queue:
                step, take = self._queue.popleft()
                if take:
                    self._frames_out += 1
                if self.stopped is not None:
                    continue
                try:
                    self._handle(step, take)
                except Exception as exc:
                    self._stop(exc)
            if self._closing.is_set() and not self._queue:
                break
        if self.stopped is None:
            try:
                for incident in list(self._open):
                    self._finish(incident, cut_short=True)
            except Exception as exc:
                self._stop(exc)
        if self._store is not None:
            with contextlib.suppress(Exception):
                self._store.close()

    def _stop(self, exc: BaseException) -> None:
        """Recording stops for good; the open clips are closed best effort."""
        if self.stopped is not None:
            return
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        self.stopped = text
        for incident in self._open:
            for writer in incident.writers.values():
                with contextlib.suppress(Exception):
                    writer.close()
        self._open.clear()
        self.rings = {c: FrameRing(r.window_s, r.budget_bytes) for c, r in self.rings.items()}
        self._raise(Alert(STOPPED_ALERT, "warning",
                          f"incident recording stopped: {text}; the monitor goes on commanding",
                          "recorder", self._now, details={"data_dir": str(self.data_dir)}))

    def _raise(self, alert: Alert) -> None:
        """An alert of the recorder's own, handed to ``on_alert`` from the next ``on_step``."""
        self.alerts_raised.append(alert)
        self._alerts.append(alert)

    def _handle(self, step: Step, take: bool) -> None:
        result = step.result
        self._now = now = result.now
        index = step.index
        events = []
        if result.changed:
            events.append(self._command_event(result, index, step.frame is None))
        if step.reset_possible:
            events.append({"type": "reset_possible", "frame": index, "time_s": _r(now),
                           "describe": self._describe(result.command)})
        events += [alert_event(a, index, None) for a in result.alerts]
        for event in events:
            self._history.append((now, event))
            for incident in self._open:
                incident.record["events"].append(event)
        while self._history and self._history[0][0] < now - self.config.pre_s:
            self._history.popleft()
        if take:
            self._frame(step)
        causes = self._triggers.update(result)
        if causes:
            self._start(step, causes)
        for incident in [i for i in self._open if now >= i.end_s]:
            self._finish(incident)
        self._retention()

    def _frame(self, step: Step) -> None:
        info = step.frame.info
        ring = self.rings.get(info.camera_id)
        if ring is None:  # a camera not named at start: gets a ring of the same budget
            first = next(iter(self.rings.values()), None)
            budget = first.budget_bytes if first else int(self.config.memory_mb * 2 ** 20)
            ring = self.rings[info.camera_id] = FrameRing(self.config.pre_s, budget)
        lite = replace(step.result, alerts=())  # snapshots stay out of the ring's memory
        ring.push(RingFrame(info.capture_time, encode_jpeg(step.frame.image,
                                                           self.config.jpeg_quality), lite))
        writing = [i for i in self._open if info.camera_id in i.writers]
        if writing:
            base = self._annotate(step.frame.image, lite, info.camera_id)
            for incident in writing:
                self._write(incident, info.camera_id, base, info.capture_time)

    def _annotate(self, image, result, camera_id: str):
        if camera_id not in self._watch:
            self._watch[camera_id] = watch_regions(self.cell, camera_id) \
                if self.cell is not None and camera_id in self.cell.cameras else []
        # one zone drawing a camera, kept: the shadow behind the occluders alone took 0.44 s a
        # frame to compute (a clip of the demo cell recorded at 2 frames a second)
        cache = self._zone_drawing.setdefault(camera_id, ZoneDrawCache())
        return overlay(image, result, self.cell, camera_id, self._watch[camera_id], self.when,
                       cache)

    def _describe(self, command) -> str:
        return describe(command) if self.when is None else describe(command, self.when)

    def _command_event(self, result, index: int, tick: bool) -> dict:
        return command_event(result, index, tick) if self.when is None \
            else command_event(result, index, tick, self.when)

    def _write(self, incident: _Open, camera_id: str, base, t: float) -> None:
        image = base.copy()
        cv2.putText(image, f"t{t - incident.time_s:+.2f} s", (12, 56),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2, cv2.LINE_AA)
        incident.writers[camera_id].write(image, t)
        clip = incident.record["clips"][camera_id]
        clip["frames"] += 1
        clip["frames_before"] += int(t <= incident.time_s)
        clip["last_s"] = _r(t - incident.time_s)
        clip.setdefault("first_s", _r(t - incident.time_s))

    def _start(self, step: Step, causes: tuple[str, ...]) -> None:
        result = step.result
        cmd = result.command
        wall = self.wall()
        self._seq += 1
        incident_id = (time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(wall))
                       + f"-{self._run_id}-{self._seq:04d}")
        reset = None
        if cmd.reset is not None:
            reset = {"operator": cmd.reset.operator, "accepted": cmd.reset.accepted,
                     "message": cmd.reset.message, "request_id": cmd.reset.request_id}
        record = {
            "schema": SCHEMA, "id": incident_id, "cell": self.cell_id, "wall": round(wall, 3),
            "time_s": _r(result.now), "frame": step.index, "causes": list(causes),
            "state": cmd.state, "latched": bool(cmd.latched), "describe": self._describe(cmd),
            "command": self._command_event(result, step.index, step.frame is None),
            "faults": [{"name": f.name, "reason": f.reason, "source": f.source}
                       for f in result.faults if f.stop],
            "reset": reset, "zones_hash": self.zones_hash, "config_hash": self.config_hash,
            # the kinds of this step's alerts: a list names them (``Incident.cause_text``)
            "alerts": list(dict.fromkeys(a.kind for a in result.alerts)),
            "window": {"pre_s": self.config.pre_s, "post_s": self.config.post_s},
            "events": [e for _, e in self._history], "clips": {}, "complete": False,
        }
        folder = self.data_dir / incident_id
        folder.mkdir()
        incident = _Open(record, result.now, result.now + self.config.post_s, folder)
        if len(self._open) >= self.config.max_open:
            record["clip_note"] = f"no clip: {len(self._open)} incidents recorded at once " \
                                  f"(max_open)"
        else:
            start = result.now - self.config.pre_s
            for camera_id, ring in self.rings.items():
                name = _file_name(camera_id)
                incident.writers[camera_id] = ClipWriter(folder / name, self.config.max_fps)
                record["clips"][camera_id] = {"file": name, "codec": CODEC, "frames": 0,
                                              "frames_before": 0}
                for frame in ring.since(start):
                    base = self._annotate(frame.image(), frame.result, camera_id)
                    self._write(incident, camera_id, base, frame.time)
        self._open.append(incident)
        self._store.put(record)
        self.incidents += 1
        self.by_cause.update(causes)
        if self.on_incident is not None:
            with contextlib.suppress(Exception):
                self.on_incident(causes)

    def _finish(self, incident: _Open, cut_short: bool = False) -> None:
        self._open.remove(incident)
        for writer in incident.writers.values():
            writer.close()
        record = incident.record
        record["commands"] = [e for e in record["events"] if e["type"] == "command"]
        record["complete"] = True
        if cut_short:
            record["cut_short"] = True  # the monitor stopped before post_s had passed
        for clip in record["clips"].values():
            if clip["frames"] == 0:  # a camera without frames in the window has no clip
                (incident.dir / clip["file"]).unlink(missing_ok=True)
                clip["file"] = None
        (incident.dir / RECORD).write_text(json.dumps(record, indent=1) + "\n")
        size = sum(p.stat().st_size for p in incident.dir.iterdir() if p.is_file())
        self._store.put(record, size, complete=True)
        self._retention(force=True)

    def _retention(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last_retention < 1.0:
            return
        self._last_retention = now
        c = self.config
        done = enforce(self._store, c.retention_days, c.max_gb, c.min_free_gb, self.wall())
        if done.blocked is not None and not self._retention_blocked:
            # said once when it starts (and again after it had cleared), not every second
            self._raise(Alert(BLOCKED_ALERT, "warning", f"incident retention: {done.blocked}",
                              "recorder", self._now,
                              details={"data_dir": str(self.data_dir)}))
        self._retention_blocked = done.blocked is not None
