"""`monitor replay video.mp4`: the live pipeline, frame by frame, on the video's own clock.

The loop is the live one (``monitor.driver.Driver``): only the feed (``VideoFeed``: the video's
frames, and timer ticks every ``tick_s`` of video time between two frames, so a gap in the
timestamps gives ``frame_timeout`` as a silent camera does live) and the sinks differ.

Outputs in DIR: ``events.jsonl`` (every command change, alert and "reset possible" with frame
index and video time; byte-identical for the same input and settings), ``annotated.mp4`` (zones,
persons, state banner, distances, health; H.264 when PyAV is installed, else MPEG-4 Part 2),
``summary.json``, and ``snapshots/`` (JPEGs of alerts). A run that is interrupted still finishes
every file it started and says so in ``summary.json`` (``interrupted``); the previous run's
summary is removed first, so no output ever pairs with another run's.
"""

from __future__ import annotations

import json
import math
import statistics
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from monitor.detector import Detector, visible
from monitor.detector.envelope import for_detector
from monitor.driver import Driver, Step, StepInputs, require_protective_zone
from monitor.errors import InputError
from monitor.frames import Frame, VideoFileReader
from monitor.health import HealthConfig
from monitor.health.build import camera_health, inplace_check
from monitor.pipeline import Pipeline
from monitor.policy import RUN, SLOW, STOP, PolicyConfig, ResetRequest
from monitor.progress import bar
from monitor.records.annotate import Annotator
from monitor.records.events import alert_event, command_event, describe
from monitor.timetext import video_time
from monitor.wire.object_accepts import ObjectAccept
from monitor.zones import Cell, watch_regions
from monitor.zones.cameras import choose_camera


@dataclass(frozen=True)
class ReplaySettings:
    out_dir: Path
    camera_id: str | None = None  # default: the zone file's only camera (several: required)
    reset_at: tuple[float, ...] = ()  # video seconds at which an operator reset is sent
    # (video seconds, zone): an operator accepts the objects standing in that zone since
    # commissioning (as `monitor objects accept`; docs/occlusion.md)
    accept_at: tuple[tuple[float, str], ...] = ()
    realtime: bool = False
    annotate: bool = True
    progress: bool = True
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    health: HealthConfig | None = field(default_factory=HealthConfig)  # None: no health checks
    reference: np.ndarray | None = None
    tick_s: float = 0.05  # timers run every tick_s of video time between frames (service.tick_s)
    allow_no_protective: bool = False  # a zone file without an enabled protective zone
    self_test_period_s: float | None = None  # the detector self-test, in seconds of video
    incidents_dir: Path | None = None  # record incidents there (monitor/incidents/)
    recorder: object = None  # RecorderConfig of the incidents (None: its defaults)
    config_hash: str = ""  # of the config file, recorded with each incident


@dataclass
class ReplaySummary:
    video: str
    frames: int = 0
    duration_s: float = 0.0
    frames_with_persons: int = 0
    max_persons: int = 0
    time_in: dict[str, float] = field(default_factory=lambda: {RUN: 0.0, SLOW: 0.0, STOP: 0.0})
    first_stop: dict | None = None
    first_slow: dict | None = None
    command_changes: int = 0  # steps whose command differs (state, latch or reasons)
    state_changes: int = 0  # of those, the ones that changed RUN / SLOW / STOP
    reason_changes: int = 0  # the others: same state, other reasons or latch
    ticks: int = 0  # timer steps between frames (video time gaps longer than tick_s)
    resets: list[dict] = field(default_factory=list)  # time, accepted, message of each reset
    alerts: dict[str, int] = field(default_factory=dict)
    fps_achieved: float = 0.0
    stage_ms_median: dict[str, float] = field(default_factory=dict)
    faults: dict[str, int] = field(default_factory=dict)  # fault name -> frames it was active
    truncated: str | None = None
    interrupted: str | None = None  # "at frame N (t s of video)" when stopped by a signal
    zones: str | None = None
    video_codec: str | None = None  # codec of annotated.mp4
    final: str | None = None  # the last command, described honestly (latched, reset possible)
    outputs: dict[str, str] = field(default_factory=dict)
    incidents: dict | None = None  # the recorder's status with --incidents

    def table(self) -> str:
        rows = [
            ("frames", f"{self.frames} ({self.duration_s:.1f} s of video)"),
            ("persons seen", f"in {self.frames_with_persons} frames, at most {self.max_persons}"),
            *[(f"time in {s}", f"{self.time_in[s]:.2f} s") for s in (RUN, SLOW, STOP)],
            ("first SLOW", _when(self.first_slow)),
            ("first STOP", _when(self.first_stop)),
            ("state changes", str(self.state_changes)),
            ("reason changes", f"{self.reason_changes} (same state, other reasons or latch)"),
            ("resets", "; ".join(_reset_text(r) for r in self.resets) or "none"),
            ("alerts", ", ".join(f"{k} x{v}" for k, v in sorted(self.alerts.items())) or "none"),
            ("faults", ", ".join(f"{k} in {v} frames" for k, v in sorted(self.faults.items()))
             or "none"),
            ("frames per second", f"{self.fps_achieved:.1f}"),
            ("zones", self.zones or "none (persons cannot cause SLOW/STOP)"),
        ]
        if self.final:
            rows.append(("at the end", self.final))
        if self.video_codec:
            rows.append(("annotated video", self.video_codec))
        if self.truncated:
            rows.append(("truncated", self.truncated))
        if self.interrupted:
            rows.append(("interrupted", self.interrupted))
        if self.incidents is not None:
            rec = self.incidents
            rows.append(("incidents", f"{rec['incidents']} in {rec['data_dir']}" + (
                f" (recording stopped: {rec['stopped']})" if rec["stopped"] else "")))
        width = max(len(k) for k, _ in rows)
        return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def _reset_text(reset: dict) -> str:
    verdict = "accepted" if reset["accepted"] else reset["message"]
    return f"{reset['time_s']:.2f} s {verdict}"


def _when(event: dict | None) -> str:
    return "never" if event is None else f"frame {event['frame']} at {event['time_s']:.2f} s"


def _r(value: float) -> float:
    return round(float(value), 4)


# --- the feed: the video's frames and the timer ticks between them ------------------------------

class VideoFeed:
    """Frames of a video on its own clock, with a timer tick every ``tick_s`` of video time
    between two frames (as the live loop ticks while it waits), and the operator resets of
    ``reset_at`` (and acceptances of objects since commissioning, ``accept_at``) at the first
    step at or after their time (a negative time: at frame 0)."""

    def __init__(self, reader: VideoFileReader, tick_s: float, reset_at: tuple[float, ...],
                 realtime: bool = False, stop: threading.Event | None = None,
                 accept_at: tuple[tuple[float, str], ...] = (), camera_id: str = "video"
                 ) -> None:
        self.reader = iter(reader)
        self.camera_id = camera_id  # the camera whose objects ``accept_at`` accepts
        self.pending_accepts = sorted(accept_at)
        self.stop = stop or threading.Event()  # ends a --realtime wait at once
        self.tick_s = tick_s
        self.pending_resets = sorted(reset_at)
        self.realtime = realtime
        self.previous: float | None = None  # time of the previous frame
        self.queued: Frame | None = None
        self.next_tick: float | None = None
        self.first_time: float | None = None
        self.started = time.perf_counter()

    def next(self, idle: bool = False) -> tuple[Frame | None, float] | None:
        # ``idle`` is for live feeds: here the ticks come every tick_s of video time anyway
        if self.queued is None:
            frame = next(self.reader, None)
            if frame is None:
                return None
            self.queued = frame
            if self.previous is not None:
                self.next_tick = self.previous + self.tick_s
        t = self.queued.info.capture_time
        # a tick only where no frame is due within a hair of it (float noise is no gap)
        if self.next_tick is not None and self.next_tick < t - 1e-6:
            now, self.next_tick = self.next_tick, self.next_tick + self.tick_s
            self._pace(now)
            return None, now
        frame, self.queued, self.next_tick, self.previous = self.queued, None, None, t
        if self.first_time is None:
            self.first_time = t
        self._pace(t)
        return frame, t

    def inputs(self, now: float) -> StepInputs:
        reset = None
        if self.pending_resets and now >= self.pending_resets[0]:
            self.pending_resets.pop(0)
            reset = ResetRequest("replay", now, request_id=f"reset-at-{now:.3f}")
        accepts = []
        while self.pending_accepts and now >= self.pending_accepts[0][0]:
            _, zone = self.pending_accepts.pop(0)
            # the wall time of a replayed acceptance is its video time (a replay is repeatable)
            accepts.append(ObjectAccept("replay", self.camera_id, zone,
                                        f"accept-at-{now:.3f}-{zone}", now, now))
        return StepInputs(reset=reset, accepts=tuple(accepts))

    def _pace(self, t: float) -> None:
        if not self.realtime:
            return
        delay = self.started + t - (self.first_time or 0.0) - time.perf_counter()
        if delay > 0:
            self.stop.wait(delay)  # a long gap in the timestamps must not delay a Ctrl-C


# --- the sinks: events.jsonl, summary, annotated video, progress, a callback ---------------------

class EventsSink:
    """Every command change, alert (with its snapshot) and "reset possible" into events.jsonl."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.path = out / "events.jsonl"
        self.file = self.path.open("w")

    def on_step(self, step: Step) -> None:
        result = step.result
        tick = step.frame is None
        if result.changed:
            self._write(command_event(result, step.index, tick))
        if step.reset_possible:
            cmd = result.command
            self._write({"type": "reset_possible", "frame": step.index,
                         "time_s": _r(result.now), "describe": describe(cmd)})
        for alert in result.alerts:
            snap = None
            if alert.snapshot_jpeg:
                snap = f"snapshots/{max(step.index, 0):06d}_{alert.kind}.jpg"
                (self.out / snap).write_bytes(alert.snapshot_jpeg)
            self._write(alert_event(alert, step.index, snap))

    def _write(self, event: dict) -> None:
        self.file.write(json.dumps(event) + "\n")

    def close(self) -> None:
        self.file.close()


class SummarySink:
    """Counts for summary.json: time in each state, first SLOW / STOP, changes, resets."""

    def __init__(self, summary: ReplaySummary) -> None:
        self.s = summary
        self.prev: tuple[float, str] | None = None
        self.prev_state: str | None = None
        self.stage_samples: dict[str, list[float]] = {}
        self.alerts: Counter[str] = Counter()
        self.faults: Counter[str] = Counter()
        self.last_command = None
        self.last_index = -1

    def on_step(self, step: Step) -> None:
        s, result = self.s, step.result
        t, cmd = result.now, result.command
        if self.prev is not None:
            s.time_in[self.prev[1]] += t - self.prev[0]
        self.prev = (t, cmd.state)
        self.last_command = cmd
        self.last_index = step.index
        if step.frame is not None:
            s.frames += 1
            n = len(result.persons) if result.persons is not None else 0
            s.frames_with_persons += int(n > 0)
            s.max_persons = max(s.max_persons, n)
            for fault in {f.name for f in result.faults}:
                self.faults[fault] += 1
            for k, v in result.stage_ms.items():
                self.stage_samples.setdefault(k, []).append(v)
        else:
            s.ticks += 1
        if cmd.reset is not None:
            s.resets.append({"frame": step.index, "time_s": _r(t),
                             "accepted": cmd.reset.accepted, "message": cmd.reset.message})
        if result.changed:
            s.command_changes += 1
            if cmd.state != self.prev_state:
                s.state_changes += 1
            else:
                s.reason_changes += 1
            causes = {r.code for r in cmd.reasons} - {"startup", "clearing", "latched"}
            if cmd.state == STOP and s.first_stop is None and causes:
                s.first_stop = {"frame": step.index, "time_s": _r(t)}
            if cmd.state == SLOW and s.first_slow is None:
                s.first_slow = {"frame": step.index, "time_s": _r(t)}
        self.prev_state = cmd.state
        for alert in result.alerts:
            self.alerts[alert.kind] += 1

    def finish(self, fps: float) -> None:
        s = self.s
        if self.prev is not None:
            s.time_in[self.prev[1]] += 1.0 / fps
            s.duration_s = _r(self.prev[0] + 1.0 / fps)
        s.time_in = {k: _r(v) for k, v in s.time_in.items()}
        s.alerts = dict(self.alerts)
        s.faults = dict(self.faults)
        s.stage_ms_median = {k: round(statistics.median(v), 3)
                             for k, v in self.stage_samples.items()}
        if self.last_command is not None:
            s.final = describe(self.last_command)

    def close(self) -> None:
        pass


class VideoSink:
    """annotated.mp4: one annotated image per frame (``monitor.records.annotate``; ticks add none,
    but their resets and alerts show on the next frames). H.264 through PyAV when it is installed
    (browsers play it), else MPEG-4 Part 2 through OpenCV. ``foot_band_px`` is the detector's foot
    band the zone check used (the floor ranges drawn are the ones checked)."""

    def __init__(self, path: Path, fps: float, cell: Cell | None, camera_id: str, watch: list,
                 foot_band_px: tuple[float, float] = (0.0, 0.0), prepared=None):
        self.path, self.fps = path, fps
        self.annotator = Annotator(cell, camera_id, watch, foot_band_px, prepared=prepared)
        self.writer = None
        self.codec: str | None = None

    def on_step(self, step: Step) -> None:
        drawn = self.annotator.step(step.result,
                                    step.frame.image if step.frame is not None else None)
        if drawn is None:
            return
        image = drawn[0]
        if self.writer is None:
            self.writer, self.codec = open_video_writer(self.path, self.fps, image.shape)
        self.writer.write(image)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.release()


class CallbackSink:
    """Hands every step's result to ``publish(result)`` (the bus for --publish, or a test)."""

    def __init__(self, publish) -> None:
        self.publish = publish

    def on_step(self, step: Step) -> None:
        self.publish(step.result)

    def close(self) -> None:
        pass


class ProgressSink:
    def __init__(self, total: int, enabled: bool) -> None:
        self.bar = bar(total, "replay", "frame", enabled=enabled)

    def on_step(self, step: Step) -> None:
        if step.frame is not None:
            self.bar.update(1)

    def close(self) -> None:
        self.bar.close()


class _H264Writer:
    """H.264 (libx264, yuv420p) into an MP4 through PyAV; ``write(bgr)``, ``release()``."""

    def __init__(self, path: Path, fps: float, shape: tuple[int, ...]) -> None:
        import fractions

        import av

        self.container = av.open(str(path), mode="w")
        try:
            rate = fractions.Fraction(fps).limit_denominator(1001)
            self.stream = self.container.add_stream("libx264", rate=rate)
            # yuv420p needs even sizes: the last row/column is dropped when odd
            self.stream.width, self.stream.height = shape[1] // 2 * 2, shape[0] // 2 * 2
            self.stream.pix_fmt = "yuv420p"
            # zerolatency: no lookahead or B-frames, so closing (also after Ctrl-C) is instant
            self.stream.options = {"preset": "veryfast", "crf": "23", "tune": "zerolatency"}
        except Exception:
            self.container.close()
            raise
        self.av = av

    def write(self, image: np.ndarray) -> None:
        h, w = self.stream.height, self.stream.width
        frame = self.av.VideoFrame.from_ndarray(np.ascontiguousarray(image[:h, :w]),
                                                format="bgr24")
        for packet in self.stream.encode(frame):
            self.container.mux(packet)

    def release(self) -> None:
        try:
            for packet in self.stream.encode():
                self.container.mux(packet)
        finally:
            self.container.close()


def open_video_writer(path: Path, fps: float, shape: tuple[int, ...]):
    """(writer, codec description): H.264 where PyAV with libx264 is installed, else mp4v."""
    try:
        return _H264Writer(path, fps, shape), "H.264 (libx264 via PyAV)"
    except Exception:  # PyAV missing or built without libx264: the portable fallback
        pass
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                             (shape[1], shape[0]))
    if not writer.isOpened():
        raise InputError(f"{path}: cannot open a video writer")
    return writer, "MPEG-4 Part 2 (mp4v; install PyAV for H.264)"


# --- the replay ----------------------------------------------------------------------------------

def replay(video: str | Path, detector: Detector, cell: Cell | None, settings: ReplaySettings,
           publish=None, stop: threading.Event | None = None) -> ReplaySummary:
    """Run the pipeline over a video file. ``publish(result)`` is called per step if given
    (frames and ticks). When ``stop`` is set the run ends early; every output is still
    finished and ``summary.interrupted`` says where it stopped."""
    video = Path(video)
    camera_id = settings.camera_id or "video"  # without a zone file the name is only a label
    expected = None
    if cell is not None:
        # the zone file's only camera, or the one --camera names (several: required)
        camera_id = choose_camera(cell.cameras, settings.camera_id, cell.label)
        require_protective_zone(cell, settings.allow_no_protective, cell.label)
        spec = cell.cameras[camera_id]
        expected = (spec.width, spec.height)
    reader = VideoFileReader(video, camera_id, expected_size=expected, strict=False)
    reader.open()  # raises a one-line InputError for missing / unreadable / wrong-size videos
    _check_reset_times(video, settings.reset_at, reader.frame_count, reader.fps)
    _check_reset_times(video, tuple(t for t, _ in settings.accept_at), reader.frame_count,
                       reader.fps, "--accept-at")
    out = settings.out_dir
    out.mkdir(parents=True, exist_ok=True)
    _clear_previous(out)
    (out / "snapshots").mkdir(exist_ok=True)
    watch = watch_regions(cell, camera_id) if cell is not None else []
    # the model's envelope and the in-place check, as `monitor run` has them (docs/health.md)
    envelope = for_detector(detector, settings.health.envelope_min_recall) \
        if settings.health is not None else None
    health = camera_health(settings.health, camera_id, settings.reference, cell, envelope) \
        if settings.health is not None else None
    pipeline = Pipeline(detector, camera_id, settings.policy, cell, health,
                        references={camera_id: settings.reference})
    needed = visible.for_detector(detector, settings.health.envelope_min_recall) \
        if settings.health is not None else None
    pipeline.visible_fraction = needed.needed if needed is not None else None
    pipeline.when = video_time  # reason texts name a time where annotated.mp4 shows it
    summary = ReplaySummary(str(video), zones=cell.label if cell is not None else None)
    fps = reader.fps or 10.0
    counts = SummarySink(summary)
    events = EventsSink(out)
    sinks: list = [counts, events]
    video_sink = None
    if settings.annotate:
        band = (0.0, detector.foot_uncertainty_px(*expected)) if expected else (0.0, 0.0)
        video_sink = VideoSink(out / "annotated.mp4", fps, cell, camera_id, watch, band,
                               prepared=pipeline.prepared)
        sinks.append(video_sink)
    if publish is not None:
        sinks.append(CallbackSink(publish))
    sinks.append(ProgressSink(reader.frame_count, settings.progress))
    # the recorder's own alert (recording stopped) goes into events.jsonl like any alert
    recorder = _recorder(settings, camera_id, cell,
                         lambda a: events._write(alert_event(a, counts.last_index, None)))
    if recorder is not None:
        sinks.append(recorder)
    inplace = inplace_check(detector, cell, [camera_id], settings.health.inplace_period_s) \
        if settings.health is not None else None
    driver = Driver(pipeline, sinks, self_test_period_s=settings.self_test_period_s,
                    inplace=inplace)
    stop = stop or threading.Event()
    feed = VideoFeed(reader, settings.tick_s, settings.reset_at, settings.realtime, stop,
                     settings.accept_at, camera_id)
    start = time.perf_counter()
    try:
        driver.run(feed, stop)
    finally:
        reader.close()
        driver.close()
    if stop.is_set():
        last = counts.prev[0] if counts.prev else 0.0
        summary.interrupted = f"at frame {counts.last_index} ({last:.2f} s of video)"
    counts.finish(fps)
    elapsed = time.perf_counter() - start
    summary.fps_achieved = round(summary.frames / elapsed, 2) if elapsed > 0 else 0.0
    if recorder is not None:
        summary.incidents = recorder.status()
    if reader.truncation is not None:
        summary.truncated = str(reader.truncation)
    if summary.frames == 0 and not stop.is_set():
        raise InputError(f"{video}: no frame could be read")
    summary.outputs = {"events": str(events.path), "summary": str(out / "summary.json")}
    if video_sink is not None and video_sink.codec is not None:
        summary.outputs["annotated"] = str(out / "annotated.mp4")
        summary.video_codec = video_sink.codec
    (out / "summary.json").write_text(json.dumps(summary.__dict__, indent=2) + "\n")
    return summary


def _recorder(settings: ReplaySettings, camera_id: str, cell: Cell | None, on_alert):
    """The incident recorder of ``--incidents DIR`` (lossless: a replay waits for it)."""
    if settings.incidents_dir is None:
        return None
    from monitor.incidents.recorder import IncidentRecorder
    from monitor.incidents.settings import RecorderConfig

    return IncidentRecorder(settings.recorder or RecorderConfig(enabled=True),
                            settings.incidents_dir, [camera_id], cell, cell_id="replay",
                            config_hash=settings.config_hash, on_alert=on_alert,
                            lossless=True)


def _check_reset_times(video: Path, reset_at: tuple[float, ...], frames: int,
                       fps: float | None, option: str = "--reset-at") -> None:
    """A reset time must lie within the video: one that never comes is a typo, not a plan."""
    for t in reset_at:
        if not math.isfinite(t) or t < 0:
            raise InputError(f"{option} {t:g}: not a video time (0 or more seconds)")
    if frames and fps:
        length = frames / fps
        late = [t for t in reset_at if t >= length]
        if late:
            raise InputError(f"{option} {late[0]:g}: past the end of {video.name} "
                             f"({length:.2f} s, {frames} frames)")


def _clear_previous(out: Path) -> None:
    """Remove the previous run's outputs first: a new run's files never sit beside an old
    summary (whatever happens to this run, even a kill)."""
    for name in ("summary.json", "events.jsonl", "annotated.mp4"):
        (out / name).unlink(missing_ok=True)
    snapshots = out / "snapshots"
    if snapshots.is_dir():
        for jpeg in snapshots.glob("*.jpg"):
            jpeg.unlink()
