"""`monitor replay video.mp4`: the live pipeline, frame by frame, on the video's own clock.

Outputs in DIR: ``events.jsonl`` (every command change and alert with frame index and video
time; byte-identical for the same input and settings), ``annotated.mp4`` (zones, persons, state
banner, distances, health), ``summary.json``, and ``snapshots/`` (JPEGs of alerts).
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from monitor.detector import Detector
from monitor.errors import InputError
from monitor.frames import VideoFileReader
from monitor.health import CameraHealth, HealthConfig, draw_health
from monitor.pipeline import Pipeline, StepResult
from monitor.policy import RUN, SLOW, STOP, PolicyConfig, ResetRequest
from monitor.types import Alert
from monitor.zones import Cell, draw_zones, watch_regions

STATE_BGR = {RUN: (60, 170, 60), SLOW: (0, 170, 255), STOP: (40, 40, 220)}


@dataclass(frozen=True)
class ReplaySettings:
    out_dir: Path
    camera_id: str | None = None  # default: the zone file's only camera, else "video"
    reset_at: tuple[float, ...] = ()  # video seconds at which an operator reset is sent
    realtime: bool = False
    annotate: bool = True
    progress: bool = True
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    health: HealthConfig | None = field(default_factory=HealthConfig)  # None: no health checks
    reference: np.ndarray | None = None


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
    command_changes: int = 0
    resets: list[dict] = field(default_factory=list)  # time, accepted, message of each reset
    alerts: dict[str, int] = field(default_factory=dict)
    fps_achieved: float = 0.0
    stage_ms_median: dict[str, float] = field(default_factory=dict)
    faults: dict[str, int] = field(default_factory=dict)  # fault name -> frames it was active
    truncated: str | None = None
    zones: str | None = None
    outputs: dict[str, str] = field(default_factory=dict)

    def table(self) -> str:
        rows = [
            ("frames", f"{self.frames} ({self.duration_s:.1f} s of video)"),
            ("persons seen", f"in {self.frames_with_persons} frames, at most {self.max_persons}"),
            *[(f"time in {s}", f"{self.time_in[s]:.2f} s") for s in (RUN, SLOW, STOP)],
            ("first SLOW", _when(self.first_slow)),
            ("first STOP", _when(self.first_stop)),
            ("command changes", str(self.command_changes)),
            ("resets", "; ".join(_reset_text(r) for r in self.resets) or "none"),
            ("alerts", ", ".join(f"{k} x{v}" for k, v in sorted(self.alerts.items())) or "none"),
            ("faults", ", ".join(f"{k} in {v} frames" for k, v in sorted(self.faults.items()))
             or "none"),
            ("frames per second", f"{self.fps_achieved:.1f}"),
            ("zones", self.zones or "none (persons cannot cause SLOW/STOP)"),
        ]
        if self.truncated:
            rows.append(("truncated", self.truncated))
        width = max(len(k) for k, _ in rows)
        return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def _reset_text(reset: dict) -> str:
    verdict = "accepted" if reset["accepted"] else reset["message"]
    return f"{reset['time_s']:.2f} s {verdict}"


def _when(event: dict | None) -> str:
    return "never" if event is None else f"frame {event['frame']} at {event['time_s']:.2f} s"


def _r(value: float) -> float:
    return round(float(value), 4)


def command_event(result: StepResult, index: int) -> dict:
    """A command change as it goes into events.jsonl (no wall-clock values: deterministic)."""
    cmd = result.command.to_dict()
    reasons = [{k: (_r(v) if isinstance(v, float) else v) for k, v in r.items()}
               for r in cmd["reasons"]]
    event = {"type": "command", "frame": index, "time_s": _r(result.now), "state": cmd["state"],
             "speed_scale": _r(cmd["speed_scale"]), "latched": cmd["latched"],
             "reasons": reasons}
    if "reset" in cmd:
        event["reset"] = cmd["reset"]
    return event


def alert_event(alert: Alert, index: int, snapshot: str | None) -> dict:
    event = {"type": "alert", "frame": index, "time_s": _r(alert.time), "kind": alert.kind,
             "severity": alert.severity, "source": alert.source, "message": alert.message}
    if snapshot:
        event["snapshot"] = snapshot
    return event


def annotate(image: np.ndarray, result: StepResult, cell: Cell | None, camera_id: str,
             watch: list) -> np.ndarray:
    """The frame with zones, persons, the state banner, distances and health drawn on."""
    hits = {h.zone_id for h in result.zone_report.hits} if result.zone_report else set()
    out = draw_zones(image, cell, camera_id, hits) if cell is not None else image.copy()
    if result.health is not None:
        draw_health(out, result.health, watch)
    persons = result.persons
    in_zone: dict[int, str] = {}
    for hit in result.zone_report.hits if result.zone_report else ():
        if in_zone.get(hit.person) != "protective":  # the worst zone colours the box
            in_zone[hit.person] = hit.kind
    if persons is not None:
        for k, (x1, y1, x2, y2) in enumerate(persons.boxes_px):
            kind = in_zone.get(k)
            colour = (40, 40, 220) if kind == "protective" else \
                (0, 170, 255) if kind == "warning" else (60, 200, 60)
            cv2.rectangle(out, (int(x1), int(y1)), (int(x2) - 1, int(y2) - 1), colour, 3)
            cv2.putText(out, f"person {k} {persons.scores[k]:.2f}", (int(x1), max(14, int(y1) - 6)),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2)
    cmd = result.command
    h, w = out.shape[:2]
    cv2.rectangle(out, (0, h - 44), (w, h), STATE_BGR[cmd.state], -1)
    text = f"{cmd.state}  x{cmd.speed_scale:.2f}" + ("  LATCHED - reset needed" if cmd.latched
                                                      else "")
    reason = cmd.reasons[0].message if cmd.reasons else ""
    rep = result.zone_report
    if rep is not None and rep.tool_separation_m is not None:
        text += f"  tool {rep.tool_separation_m:.2f} m"
        if rep.required_separation_m is not None:
            text += f" (needs {rep.required_separation_m:.2f} m)"
    cv2.putText(out, text, (12, h - 16), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2)
    cv2.putText(out, reason[:80], (int(w * 0.45), h - 16), cv2.FONT_HERSHEY_SIMPLEX, 0.55,
                (255, 255, 255), 1, cv2.LINE_AA)
    return out


def replay(video: str | Path, detector: Detector, cell: Cell | None, settings: ReplaySettings,
           publish=None) -> ReplaySummary:
    """Run the pipeline over a video file. ``publish(result)`` is called per step if given."""
    video = Path(video)
    camera_id = settings.camera_id or (next(iter(cell.cameras)) if cell and len(cell.cameras) == 1
                                       else "video")
    expected = None
    if cell is not None:
        if camera_id not in cell.cameras:
            raise InputError(f"camera {camera_id!r} is not in the zone file "
                             f"(has {', '.join(cell.cameras)})")
        spec = cell.cameras[camera_id]
        expected = (spec.width, spec.height)
    reader = VideoFileReader(video, camera_id, expected_size=expected, strict=False)
    reader.open()  # raises a one-line InputError for missing / unreadable / wrong-size videos
    out = settings.out_dir
    out.mkdir(parents=True, exist_ok=True)
    (out / "snapshots").mkdir(exist_ok=True)
    watch = watch_regions(cell, camera_id) if cell is not None else []
    health = CameraHealth(settings.health, camera_id, settings.reference, watch) \
        if settings.health is not None else None
    pipeline = Pipeline(detector, camera_id, settings.policy, cell, health)
    summary = ReplaySummary(str(video), zones=cell.label if cell is not None else None)
    pending_resets = sorted(settings.reset_at)
    fps = reader.fps or 10.0
    writer = None
    stage_samples: dict[str, list[float]] = {}
    alerts: Counter[str] = Counter()
    faults: Counter[str] = Counter()
    progress = _progress(reader.frame_count, settings.progress)
    start = time.perf_counter()
    prev: tuple[float, str] | None = None
    first_time = 0.0
    events_path = out / "events.jsonl"
    try:
        with events_path.open("w") as events:
            for frame in reader:
                t = frame.info.capture_time
                index = frame.info.seq
                reset = None
                if pending_resets and t >= pending_resets[0]:
                    pending_resets.pop(0)
                    reset = ResetRequest("replay", t, request_id=f"reset-at-{t:.3f}")
                result = pipeline.process(frame.image, frame.info, t, reset=reset)
                if prev is None:
                    first_time = t
                if prev is not None:
                    summary.time_in[prev[1]] += t - prev[0]
                prev = (t, result.command.state)
                summary.frames += 1
                n = len(result.persons) if result.persons is not None else 0
                summary.frames_with_persons += int(n > 0)
                summary.max_persons = max(summary.max_persons, n)
                outcome = result.command.reset
                if outcome is not None:
                    summary.resets.append({"frame": index, "time_s": _r(t),
                                           "accepted": outcome.accepted,
                                           "message": outcome.message})
                if result.changed:
                    summary.command_changes += 1
                    events.write(json.dumps(command_event(result, index)) + "\n")
                    state = result.command.state
                    causes = {r.code for r in result.command.reasons} - {"startup", "clearing"}
                    if state == STOP and summary.first_stop is None and causes:
                        summary.first_stop = {"frame": index, "time_s": _r(t)}
                    if state == SLOW and summary.first_slow is None:
                        summary.first_slow = {"frame": index, "time_s": _r(t)}
                for fault in {f.name for f in result.faults}:
                    faults[fault] += 1
                for alert in result.alerts:
                    alerts[alert.kind] += 1
                    snap = None
                    if alert.snapshot_jpeg:
                        snap = f"snapshots/{index:06d}_{alert.kind}.jpg"
                        (out / snap).write_bytes(alert.snapshot_jpeg)
                    events.write(json.dumps(alert_event(alert, index, snap)) + "\n")
                for k, v in result.stage_ms.items():
                    stage_samples.setdefault(k, []).append(v)
                if settings.annotate:
                    image = annotate(frame.image, result, cell, camera_id, watch)
                    if writer is None:
                        writer = _writer(out / "annotated.mp4", fps, image.shape)
                    writer.write(image)
                if publish is not None:
                    publish(result)
                if settings.realtime:
                    _pace(start, t - first_time)
                progress.update(1)
    finally:
        progress.close()
        reader.close()
        if writer is not None:
            writer.release()
    if prev is not None:
        summary.time_in[prev[1]] += 1.0 / fps
        summary.duration_s = _r(prev[0] + 1.0 / fps)
    summary.time_in = {k: _r(v) for k, v in summary.time_in.items()}
    elapsed = time.perf_counter() - start
    summary.fps_achieved = round(summary.frames / elapsed, 2) if elapsed > 0 else 0.0
    summary.alerts = dict(alerts)
    summary.faults = dict(faults)
    summary.stage_ms_median = {k: round(statistics.median(v), 3)
                               for k, v in stage_samples.items()}
    if reader.truncation is not None:
        summary.truncated = str(reader.truncation)
    if summary.frames == 0:
        raise InputError(f"{video}: no frame could be read")
    summary.outputs = {"events": str(events_path), "summary": str(out / "summary.json")}
    if settings.annotate:
        summary.outputs["annotated"] = str(out / "annotated.mp4")
    (out / "summary.json").write_text(json.dumps(summary.__dict__, indent=2) + "\n")
    return summary


def _writer(path: Path, fps: float, shape: tuple[int, ...]) -> cv2.VideoWriter:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                             (shape[1], shape[0]))
    if not writer.isOpened():
        raise InputError(f"{path}: cannot open a video writer")
    return writer


def _pace(start: float, video_time: float) -> None:
    delay = start + video_time - time.perf_counter()
    if delay > 0:
        time.sleep(delay)


class _NoProgress:
    def update(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass


def _progress(total: int, enabled: bool):
    if not (enabled and sys.stderr.isatty()):
        return _NoProgress()
    from tqdm import tqdm

    return tqdm(total=total or None, unit="frame", desc="replay", leave=False)
