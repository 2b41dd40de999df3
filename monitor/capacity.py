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
  under ``policy.max_frame_age``;
- the gap between two decisions (one frame) must stay under ``bus.stall_timeout``, or the bus
  publishes "stalled" STOPs between them, and a cycle under ``policy.frame_timeout``;
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
    """The limits a step must stay within (seconds), from ``[policy]`` and ``[bus]``."""

    frame_timeout: float
    max_frame_age: float
    stall_timeout: float


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
    """The verdict for a measured bare detection time ``detect_s`` (seconds). Pure."""
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
    fps, age = {}, {}
    for cam in cameras:
        interval = cycle if cam.max_fps is None else max(cycle, 1.0 / cam.max_fps)
        fps[cam.camera_id] = 1.0 / interval
        age[cam.camera_id] = interval + latency
    hints = ["fewer cameras", "a smaller [detector] input_size", "an int8 model",
             "a faster host"]
    problems, warnings = [], []

    def check(value: float, limit: float, what: str, name: str) -> None:
        if not value < limit:
            problems.append(f"{what} {value * 1e3:.0f} ms >= {name} {limit * 1e3:.0f} ms")
        elif value > THIN_MARGIN * limit:
            warnings.append(f"thin margin: {what} {value * 1e3:.0f} ms of {name} "
                            f"{limit * 1e3:.0f} ms")

    check(frame_s, limits.stall_timeout, "one frame's step", "bus.stall_timeout")
    check(cycle, limits.frame_timeout, f"a cycle of {n} camera(s)", "policy.frame_timeout")
    worst = max(age, key=age.get)
    check(age[worst], limits.max_frame_age, f"{worst}'s frame age", "policy.max_frame_age")
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
    return Capacity(frame_s, cycle, age, fps, capacity_fps, refusal, tuple(warnings), latency)


def decode_time_s(width: int, height: int) -> float:
    """The allowance for reading and decoding one frame of this size (seconds)."""
    return DECODE_S_PER_MP * width * height / 1e6


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
