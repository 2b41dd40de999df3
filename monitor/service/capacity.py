"""Capacity: can this host watch this cell within the policy's limits? Measured at start.

A host too slow for its config does not fail safe quietly: it STOPs all the time (stalls, stale
frames, a consumer flipping RUN/STOP on the bus's ``stall_timeout``) and nobody learns why. So
``monitor run`` times the detector on a frame of each camera's size with the configured
threads, and this module's pure ``assess`` compares that with the config:

- cameras run in turn, so one *cycle* (every camera processed once) costs ``n x frame_s``;
  ``frame_s`` is the measured detection time times ``PIPELINE_FACTOR`` (the rest of a step:
  tracks, zones, health, policy, publishing; the pipeline benchmark measures bare inference at
  0.74 of a whole step at 1080p) plus the time to read and decode a frame, ``DECODE_S_PER_MP``
  per megapixel of the camera's frame (it grows with the resolution);
- a frame's *latency* (capture to decision) is the worst case of cameras in turn: every
  camera's frame arrives at once and this one is processed last, ``n`` steps after its own
  decoding, each step slowed by the other cameras' grabbers decoding on the same cores
  (``CONTENTION`` per further camera), plus ``TAIL_S`` for the p99 tail (scheduler, GC,
  onnxruntime threads waking): ``TAIL_S + decode + n x step x (1 + CONTENTION x (n - 1))``;
- a camera's newest processed frame is at most ``max(cycle, 1 / max_fps) + latency`` old when
  the policy decides (a whole interval until the next one is decided on): that must stay
  under ``policy.max_frame_age`` (``frame_stale``; ``frame_late`` judges less, the latency)
  and under ``health.lost_after_s`` (``camera_lost``: issue 29, at ~1 fps a camera was "lost"
  between every two of its frames);
- one step at p99 (``TAIL_S + decode + step x (1 + CONTENTION x (n - 1))``) is the gap between
  two decisions: it must stay under ``bus.stall_timeout``, or the bus publishes "stalled"
  STOPs between them; the gap between two decisions on a frame (the shortest camera interval
  + latency - one frame) under ``policy.frame_timeout`` (``frame_timeout``; the loop's stall
  timer, a latched ``monitor_stalled``, uses the same limit on the shorter gap of a step);
- cameras with ``max_fps`` ask for ``sum(max_fps)`` frames a second: more than the host
  processes is refused.

Where the constants come from: ``benchmarks/capacity.py`` on a quiet 2-core host (1080p
cameras paced at 10 fps, 2 inference threads; a 1080p frame decodes in 3.5 ms, 1.7 ms per
megapixel). Measured p99 capture-to-decision latency: int8 (10.1 ms detection) 39 / 52 / 137 ms
at 1 / 2 / 4 cameras, fp32 (19.1 ms) 53 / 66 / 228 ms. The former fixed 3 ms read allowance and
one step of latency predicted 117 and 144 ms frame ages at 4 cameras, under those latencies
alone: the decoding of 4 streams competing with inference for 2 cores and the tail were
missing. ``TAIL_S`` covers the 1-camera p99 (25 ms over decode + step) and ``CONTENTION``
the 4-camera one (0.4: int8 149 >= 137 ms, fp32 256 >= 228 ms predicted); they stay
conservative on more cores. The processed fps keeps the throughput model (``frame_s``, measured
9.0 fps against 8.7 predicted for fp32 at 4 cameras): the contention delays frames that arrive
together, it does not lower the average rate.

It refuses (one line saying what to change) when a limit is exceeded and warns when a figure
uses more than ``THIN_MARGIN`` of its limit. What it cannot know: a camera's real frame rate
(set ``max_fps``), and load that comes later (the stall detector and ``frame_stale`` still
STOP then).
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from monitor.errors import ConfigError

# a whole step costs this many times the bare detection (benchmarks/pipeline.py: 0.74 at 1080p)
PIPELINE_FACTOR = 1.35
# reading and decoding one frame, per megapixel (benchmarks/capacity.py: 3.5 ms for a 1080p
# frame on a quiet host = 1.7 ms/MP; 1080p H.264 1.5-2 ms): 1080p gets 4.1 ms
DECODE_S_PER_MP = 0.002
# each further camera slows a step by this share while frames arrive together: its grabber
# decodes on the same cores (benchmarks/capacity.py: 4 cameras on 2 cores, see above)
CONTENTION = 0.4
# the p99 tail of a frame's latency over decode + steps (benchmarks/capacity.py: 1 camera)
TAIL_S = 0.025
# a figure above this share of its limit is a warning: little room for load or a slower frame
THIN_MARGIN = 0.7
TIMED_RUNS = 5


@dataclass(frozen=True)
class CameraDemand:
    """What the config asks of one camera: its id, frame size and ``max_fps`` (None: as fast
    as frames come)."""

    camera_id: str
    width: int
    height: int
    max_fps: float | None = None


@dataclass(frozen=True)
class Limits:
    """The timers that STOP when frames come too rarely (seconds), from ``[policy]``,
    ``[bus]`` and ``[health]``. ``frame_timeout`` is also the loop's stall timer
    (``monitor_stalled``, latched); ``max_frame_age`` also ``frame_late``."""

    frame_timeout: float
    max_frame_age: float
    stall_timeout: float
    lost_after_s: float


@dataclass(frozen=True)
class Capacity:
    """The verdict: the figures, the refusal (None: it can start) and warnings."""

    frame_s: float  # one camera's step, measured
    cycle_s: float  # every camera once, in turn
    frame_age_s: dict[str, float]  # worst age of each camera's newest frame at a decision
    processed_fps: dict[str, float]  # how often each camera is processed
    frames_per_s: float  # what the host processes in all
    refusal: str | None
    warnings: tuple[str, ...]
    latency_s: float = 0.0  # p99 capture to decision of a frame, cameras in turn
    step_s: float = 0.0  # p99 of one step (the gap between two decisions)
    frame_gap_s: float = 0.0  # p99 gap between two decisions on a frame
    detect_s: float = 0.0  # the measured bare detection time it was predicted from

    def describe(self) -> str:
        """One log line with the figures."""
        cams = ", ".join(f"{c} {self.processed_fps[c]:.1f} fps (frame age <= "
                         f"{self.frame_age_s[c] * 1e3:.0f} ms)" for c in self.processed_fps)
        return (f"capacity: {self.frame_s * 1e3:.1f} ms a frame, {self.frames_per_s:.1f} frames/s "
                f"in all; cycle {self.cycle_s * 1e3:.0f} ms; latency <= "
                f"{self.latency_s * 1e3:.0f} ms; {cams}")

    def to_dict(self) -> dict:
        return {"frame_ms": round(self.frame_s * 1e3, 2), "cycle_ms": round(self.cycle_s * 1e3, 1),
                "frames_per_s": round(self.frames_per_s, 2),
                "latency_ms": round(self.latency_s * 1e3, 1),
                "cameras": {c: {"fps": round(self.processed_fps[c], 2),
                                "frame_age_ms": round(self.frame_age_s[c] * 1e3, 1)}
                            for c in self.processed_fps},
                "warnings": list(self.warnings)}


def assess(detect_s: float, cameras: Sequence[CameraDemand], limits: Limits) -> Capacity:
    """The verdict for a measured bare detection time ``detect_s`` (seconds). Pure.

    Every timer that STOPs (or latches) when frames come too rarely is compared with the
    predicted figure at its p99, and a refusal names the timer and the STOP it would cause."""
    if not (detect_s > 0 and np.isfinite(detect_s)):
        raise ConfigError(f"capacity: the detector's time per frame could not be measured "
                          f"({detect_s!r} s)")
    n = len(cameras)
    decode_s = max(decode_time_s(c.width, c.height) for c in cameras)
    step_s = detect_s * PIPELINE_FACTOR
    frame_s = step_s + decode_s
    cycle = n * frame_s
    capacity_fps = 1.0 / frame_s
    latency = TAIL_S + decode_s + n * step_s * (1.0 + CONTENTION * (n - 1))
    # one step at p99: its decoding, its step slowed by the other grabbers, the tail
    step_p99 = TAIL_S + decode_s + step_s * (1.0 + CONTENTION * (n - 1))
    fps, age, interval = {}, {}, {}
    for cam in cameras:
        interval[cam.camera_id] = cycle if cam.max_fps is None else max(cycle, 1.0 / cam.max_fps)
        fps[cam.camera_id] = 1.0 / interval[cam.camera_id]
        age[cam.camera_id] = interval[cam.camera_id] + latency
    # between two decisions on a frame: the shortest interval (cameras may be in step), one
    # decided as early as possible and the next as late as the p99 latency
    frame_gap = min(interval.values()) + latency - frame_s
    hints = ["fewer cameras", "a smaller [detector] input_size", "an int8 model",
             "a faster host"]
    problems, warnings = [], []

    def check(value: float, limit: float, text: str, name: str, effect: str) -> None:
        """``text`` says what ``value`` is, with the value; ``name`` the timer, ``effect``
        what it does when the value reaches it."""
        if not value < limit:
            problems.append(f"{text} exceeds {name} {_duration(limit)} ({effect})")
        elif value > THIN_MARGIN * limit:
            warnings.append(f"thin margin: {text} of {name} {_duration(limit)}")

    def check_cameras(limit: float, name: str, effect: str) -> None:
        """A per-camera timer on the age of the camera's newest processed frame."""
        over = [c for c in age if not age[c] < limit]
        thin = [c for c in age if THIN_MARGIN * limit < age[c] < limit]
        if over or thin:
            cams = over or thin
            worst = max(cams, key=age.get)
            what = (f"{_named(cams, fps)}: a frame up to {_duration(age[worst])} old (a frame "
                    f"every {_duration(interval[worst])} + {_duration(latency)} p99 latency)")
            check(age[worst], limit, what, name, effect)

    check(step_p99, limits.stall_timeout, f"one step (p99) of {_duration(step_p99)}",
          "bus.stall_timeout", "the bus would publish \"stalled\" STOPs")
    check(frame_gap, limits.frame_timeout, f"a gap of {_duration(frame_gap)} between two "
          f"frames' decisions (p99, {n} camera(s))",
          "policy.frame_timeout",
          "frame_timeout would STOP; a step that long latches monitor_stalled")
    check_cameras(limits.max_frame_age, "policy.max_frame_age", "frame_stale would STOP")
    check_cameras(limits.lost_after_s, "health.lost_after_s", "camera_lost would STOP")
    if problems and any(c.max_fps is not None and 1.0 / c.max_fps > cycle for c in cameras):
        hints.insert(0, "a higher max_fps")  # a camera waits for its rate, not for the host
    asked = sum(c.max_fps for c in cameras if c.max_fps is not None)
    if asked and any(c.max_fps is None for c in cameras):
        asked = 0.0  # some cameras take whatever is left: the rate check needs all of them
    if asked > capacity_fps:
        rates = ", ".join(f"{c.camera_id} {c.max_fps:g}" for c in cameras)
        problems.append(f"the cameras ask for {asked:g} frames/s ({rates} fps) and this host "
                        f"processes {capacity_fps:.1f}")
        hints.insert(0, "lower max_fps")
    refusal = None
    if problems:
        refusal = (f"this host cannot watch the cell in time ({frame_s * 1e3:.1f} ms a frame "
                   f"measured): {'; '.join(problems)}; use {', '.join(hints)}, or raise the "
                   f"limit if that is safe for the cell")
    return Capacity(frame_s, cycle, age, fps, capacity_fps, refusal, tuple(warnings), latency,
                    step_p99, frame_gap, detect_s)


def _duration(seconds: float) -> str:
    return f"{seconds * 1e3:.0f} ms" if seconds < 1.0 else f"{seconds:.2f} s"


def _named(cams: list[str], fps: dict[str, float]) -> str:
    """"cam0 and cam1 at a predicted 0.9 fps per camera" (each its rate when they differ)."""
    names = cams[0] if len(cams) == 1 else f"{', '.join(cams[:-1])} and {cams[-1]}"
    rates = {f"{fps[c]:.2g}" for c in cams}
    if len(rates) == 1:
        return f"{names} at a predicted {rates.pop()} fps" + (" per camera" if len(cams) > 1
                                                             else "")
    return "predicted " + ", ".join(f"{c} {fps[c]:.2g} fps" for c in cams)


def decode_time_s(width: int, height: int) -> float:
    """The allowance for reading and decoding one frame of this size (seconds)."""
    return DECODE_S_PER_MP * width * height / 1e6


def cameras_served(detect_s: float, width: int, height: int, fps: float | None,
                   limits: Limits, most: int = 16) -> tuple[int, float]:
    """How many cameras of ``width`` x ``height`` at ``fps`` each (None: as fast as frames
    come) a detector taking ``detect_s`` serves within ``limits``, and the fps each then
    gets: (0, 0.0) when not even one. Pure."""
    served = (0, 0.0)
    for n in range(1, most + 1):
        verdict = assess(detect_s, [CameraDemand(f"cam{i}", width, height, fps)
                                    for i in range(n)], limits)
        if verdict.refusal is not None:
            break
        served = (n, min(verdict.processed_fps.values()))
    return served


def measure_detect_s(detect: Callable[[np.ndarray], object], sizes: Sequence[tuple[int, int]],
                     runs: int = TIMED_RUNS, clock: Callable[[], float] = time.perf_counter,
                     stopped: Callable[[], bool] = lambda: False) -> float | None:
    """The median time (s) of ``detect`` on a grey frame of each (width, height), the largest
    of them: the slowest camera sets the pace of the others in turn. None when ``stopped()``
    turns true on the way (a shutdown signal: nothing to decide any more)."""
    worst = 0.0
    for width, height in sizes:
        frame = np.full((height, width, 3), 114, np.uint8)
        frame[::7, ::5] = 90  # not a flat image: letterbox and decode do their usual work
        detect(frame)  # warm caches for this size
        times = []
        for _ in range(runs):
            if stopped():
                return None
            t0 = clock()
            detect(frame)
            times.append(clock() - t0)
        worst = max(worst, statistics.median(times))
    return worst


def check(detect: Callable[[np.ndarray], object], cameras: Sequence[CameraDemand],
          limits: Limits, mode: str, stopped: Callable[[], bool] = lambda: False
          ) -> Capacity | None:
    """Measure and assess (``mode``: "refuse", "warn" or "off"); a refusal raises
    ``ConfigError`` in "refuse" mode and becomes a warning in "warn" mode. None when off or
    ``stopped()`` during the measurement."""
    if mode == "off":
        return None
    sizes = sorted({(c.width, c.height) for c in cameras})
    detect_s = measure_detect_s(detect, sizes, stopped=stopped)
    if detect_s is None:
        return None
    verdict = assess(detect_s, cameras, limits)
    if verdict.refusal is None:
        return verdict
    if mode == "refuse":
        raise ConfigError(f"{verdict.refusal} ([service] capacity_check = \"warn\" starts anyway)")
    return dataclasses.replace(verdict, refusal=None,
                               warnings=(verdict.refusal, *verdict.warnings))
