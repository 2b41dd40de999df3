"""Camera integrity checks of one camera (``CameraHealth``): lost, frozen, blinded and moved
(the policy STOPs on these) and defocused (a warning); it runs the watch zones' scene-change
check (monitor/health/scene.py) on the same analysis image when the image is sound."""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from monitor.detector.envelope import Envelope
from monitor.detector.imagestats import sharpness
from monitor.errors import InputError
from monitor.health.analysis import analysis_bgr, analysis_size
from monitor.health.conditions import EnvelopeWatch, zone_regions
from monitor.health.config import (
    BLINDED,
    CHECKS,
    DEFOCUSED,
    DEFOCUSED_CLEARED,
    FROZEN,
    LOST,
    MOVED,
    HealthConfig,
)
from monitor.health.draw import encode_jpeg
from monitor.health.report import HealthReport, ZoneStatus
from monitor.health.scene import WatchZones
from monitor.types import Alert, Fault


class _Timer:
    """How long a condition has held without a break (times on the caller's clock).

    A tiny epsilon is added so that frame times like ``i / fps`` reach a limit exactly."""

    def __init__(self) -> None:
        self.since: float | None = None

    def update(self, condition: bool, now: float) -> float:
        """Seconds the condition has held at ``now``; -1 when it does not hold."""
        if not condition:
            self.since = None
            return -1.0
        if self.since is None:
            self.since = now
        return now - self.since + 1e-9



class _Freeze:
    """Whether the picture still changes as a live camera's does (every frame, by more than
    the camera's own noise), on the caller's clock.

    A repeated picture differs from the one before by almost nothing; a codec's keyframe in
    a repeated picture is one frame that differs (0.3-0.8 grey levels for mp4v and H.264)
    between two that do not. So a frame *really* changed only when it and the frame before it
    both differ beyond the noise: a lone jump neither restarts the frozen timer nor ends a
    freeze, and ``picture_time`` (when the picture last really changed) is the time what
    the frame shows was seen. A freeze ends only after ``frozen_clear_s`` of frames that all
    differ."""

    LEARN = 300  # live differences kept for the camera's noise (20 s at 15 fps)
    RELEARN = 15  # ... their percentile taken anew after this many (1 s at 15 fps)

    def __init__(self) -> None:
        self.picture_time = 0.0
        self.active = False  # camera_frozen holds
        self.changing = True  # the newest difference was beyond the noise
        self.really_changed = True  # this frame and the one before both were
        self.run_since = 0.0  # the first frame of the newest run of differing frames
        self._run = 0  # differing frames in that run
        # differences of frames that really changed
        self._live: deque[float] = deque(maxlen=self.LEARN)
        self._noise: float | None = None  # their 10th percentile (every ``RELEARN`` frames)
        self._learned = 0

    def restart(self, now: float) -> None:
        """No earlier picture to compare with (the first frame, a blinded one): a new one."""
        self.picture_time = self.run_since = now
        self.active, self.changing, self.really_changed, self._run = False, True, True, 1

    def threshold(self, config: HealthConfig) -> float:
        """Grey levels a frame must differ by to count: ``frozen_diff``, or more on a noisy
        camera (a share of a low percentile of its live differences: a walking person or a
        moving robot raises the median, not the 10th percentile)."""
        if self._noise is None:
            return config.frozen_diff
        return max(config.frozen_diff, config.frozen_noise_share * self._noise)

    def step(self, diff: float, now: float, config: HealthConfig) -> float:
        """One frame's difference to the one before; returns the threshold it was judged by."""
        threshold = self.threshold(config)
        self.changing = diff >= threshold
        if not self.changing:
            self._run = 0
        elif self._run == 0:
            self._run, self.run_since = 1, now
        else:
            self._run += 1
        self.really_changed = self._run >= 2
        if self.really_changed:
            self.picture_time = now
            self._live.append(diff)
            self._learned += 1
            if len(self._live) >= 10 and (self._noise is None or self._learned >= self.RELEARN):
                self._noise, self._learned = float(np.percentile(self._live, 10)), 0
        if not self.active:
            self.active = (not self.really_changed
                           and now - self.picture_time + 1e-9 >= config.frozen_after_s)
        elif self._run >= 3 and now - self.run_since + 1e-9 >= config.frozen_clear_s:
            self.active = False
        return threshold


def load_reference(path: str | Path) -> np.ndarray:
    """Read a reference image (BGR uint8); raise InputError when it is missing or unreadable."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: reference image not found (make one with "
                         "'monitor reference capture')")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    return image


class CameraHealth:
    """Health and watch-zone checks of one camera; feed it every frame in order.

    ``reference_bgr`` is the commissioning image of this camera (any size with the frame's aspect
    ratio) or None. ``watch_zones`` are ``(zone_id, polygon_px)`` pairs, polygons (K, 2) in
    full-resolution pixels of this camera.

    ``envelope`` (the model's operating envelope, monitor/detector/envelope.py) adds the image
    conditions check (monitor/health/conditions.py): a STOP fault ``detector_envelope`` for
    every frame outside it, for the whole view and for each of ``protective_zones`` (``(zone_id,
    polygon_px)`` like ``watch_zones``) on its own.
    """

    def __init__(self, config: HealthConfig, camera_id: str,
                 reference_bgr: np.ndarray | None = None,
                 watch_zones: Sequence[tuple[str, np.ndarray]] = (),
                 envelope: Envelope | None = None,
                 protective_zones: Sequence[tuple[str, np.ndarray]] = ()):
        self.config = config
        self.camera_id = camera_id
        self.envelope = envelope  # the model's measured envelope (kept for a zone apply)
        self._envelope = None if envelope is None else EnvelopeWatch(
            envelope, camera_id, config.envelope_margin, config.clear_time_s)
        self._protective = list(protective_zones)
        self._watch = WatchZones(config, camera_id, watch_zones)
        self._reference = reference_bgr
        self._frame_size: tuple[int, int] | None = None  # (width, height) of full frames
        self._last_frame_time: float | None = None
        self._reset_state()

    # --- set-up ---------------------------------------------------------------------------------

    def _reset_state(self) -> None:
        self._small_size: tuple[int, int] = (0, 0)
        self._scale = 1.0  # full-resolution px per analysis px
        self._watch.clear()
        self._prev_small: np.ndarray | None = None
        self._ref_small: np.ndarray | None = None  # float32 grey, analysis size
        self._ref_small_bgr: np.ndarray | None = None  # float32 BGR, analysis size
        self._ref_small_bgr_u8: np.ndarray | None = None  # the same as taken (uint8)
        self._ref_sharpness: float | None = None
        self._sharp_samples: list[float] = []
        self._window: np.ndarray | None = None
        self._timers = {name: _Timer() for name in (BLINDED, MOVED, DEFOCUSED, "focus_ok")}
        self._freeze = _Freeze()
        self._defocus_active = False
        self._last_moved: float | None = None  # when the moved check last ran
        self._moved_raw = False
        self._moved_reason = ""
        self._measures: dict[str, float] = {}
        self._defocus_reason = ""
        self._dt = 0.0  # seconds since the previous frame (for the learning rate)

    def set_reference(self, reference_bgr: np.ndarray | None) -> None:
        """Use a new reference (after a deliberate change): forgets learned state and alerts."""
        self._reference = reference_bgr
        self._frame_size = None
        self._reset_state()

    def _prepare_geometry(self, width: int, height: int) -> None:
        sw, sh = analysis_size(width, height, self.config.analysis_width)
        self._frame_size = (width, height)
        self._small_size = (sw, sh)
        self._scale = width / sw
        self._window = cv2.createHanningWindow((sw, sh), cv2.CV_32F)
        if self._reference is not None:
            rh, rw = self._reference.shape[:2]
            if abs(rw / rh - width / height) > 0.01 * width / height:
                raise InputError(f"{self.camera_id}: reference image is {rw}x{rh}, frames are "
                                 f"{width}x{height} (aspect ratios differ)")
            reference = (cv2.resize(self._reference, (width, height), interpolation=cv2.INTER_AREA)
                         if (rw, rh) != (width, height) else self._reference)
            ref_bgr, ref_grey = self._small_images(reference)
            self._ref_small_bgr_u8 = ref_bgr
            self._ref_small = ref_grey.astype(np.float32)
            self._ref_small_bgr = ref_bgr.astype(np.float32)
            self._ref_sharpness = sharpness(ref_grey)
        if self._envelope is not None:
            self._envelope.prepare(self._ref_small_bgr_u8, (width, height), sw,
                                   zone_regions(self._protective, self._scale, (sw, sh)))
        self._watch.prepare(width, height, (sw, sh), self._scale, self._ref_small_bgr)

    def _small_images(self, frame_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """BGR and grey analysis images (monitor/health/analysis.py: 2x2 pixels read per
        output pixel, 0.35 ms at 1080p)."""
        small = analysis_bgr(frame_bgr, self._small_size)
        return small, cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)

    # --- the checks -----------------------------------------------------------------------------

    def check_lost(self, now: float, last_frame_time: float | None = None) -> Fault | None:
        """camera_lost when no frame came for ``lost_after_s``. ``last_frame_time`` defaults to
        the ``now`` of the last ``check``; before any frame the camera counts as lost."""
        last = self._last_frame_time if last_frame_time is None else last_frame_time
        if last is None:
            return Fault(LOST, f"{self.camera_id}: no frame received yet", True, self.camera_id)
        age = now - last
        if age > self.config.lost_after_s:
            return Fault(LOST, f"{self.camera_id}: no frame for {age:.1f} s "
                         f"(limit {self.config.lost_after_s:g} s)", True, self.camera_id)
        return None

    def check(self, frame_bgr: np.ndarray, now: float,
              person_boxes_px: np.ndarray | None = None) -> HealthReport:
        """Check one frame (BGR uint8, full resolution) taken at ``now`` seconds.

        ``person_boxes_px`` (N, 4) ``x1, y1, x2, y2`` are the persons the detector found in this
        frame: watch zones ignore the pixels they cover and learn only while no person is in them.
        """
        t_start = time.perf_counter()
        if frame_bgr is None or frame_bgr.ndim != 3 or frame_bgr.shape[2] != 3:
            raise InputError(f"{self.camera_id}: health check needs a BGR image (H, W, 3)")
        height, width = frame_bgr.shape[:2]
        if self._frame_size is None:
            self._prepare_geometry(width, height)
        elif self._frame_size != (width, height):
            raise InputError(f"{self.camera_id}: frame size changed from "
                             f"{self._frame_size[0]}x{self._frame_size[1]} to {width}x{height}")
        previous = self._last_frame_time
        self._dt = 0.0 if previous is None else min(max(now - previous, 0.0), 1.0)
        self._last_frame_time = now
        boxes = (np.zeros((0, 4), np.float32) if person_boxes_px is None
                 else np.asarray(person_boxes_px, np.float32).reshape(-1, 4))
        timings = dict.fromkeys(CHECKS, 0.0)
        faults: list[Fault] = []
        alerts: list[Alert] = []
        self._measures = {}

        t = time.perf_counter()
        small_bgr, small = self._small_images(frame_bgr)
        timings["prepare"] = _ms(t)

        t = time.perf_counter()
        blinded = self._check_blinded(small, now)
        timings["blinded"] = _ms(t)
        if blinded is not None:
            faults.append(blinded)
        raw_bad = self._timers[BLINDED].since is not None

        if self._envelope is not None:
            t = time.perf_counter()
            outside, near, values = self._envelope.check(small, now)
            self._measures.update(values)
            faults.extend([outside] if outside else [])
            alerts.extend([near] if near else [])
            timings["envelope"] = _ms(t)

        t = time.perf_counter()
        frozen = None if raw_bad else self._check_frozen(small, now)
        if raw_bad:  # a black or white image has no texture: "frozen" cannot be judged
            self._freeze.restart(now)
        timings["frozen"] = _ms(t)
        if frozen is not None:
            faults.append(frozen)
        raw_bad = raw_bad or self._freeze.active or not self._freeze.changing
        self._prev_small = small

        if not raw_bad:
            t = time.perf_counter()
            alerts.extend(self._check_defocus(small, frame_bgr, now))
            timings["defocus"] = _ms(t)
            if self._ref_small is not None and self._due(now):
                t = time.perf_counter()
                self._check_moved(small, boxes)
                timings["moved"] = _ms(t)
        if self._defocus_active:
            faults.append(Fault(DEFOCUSED, self._defocus_reason, False, self.camera_id))
        moved_for = self._timers[MOVED].update(self._moved_raw and not raw_bad, now)
        if moved_for >= self.config.moved_after_s:
            faults.append(Fault(MOVED, self._moved_reason, True, self.camera_id))
        # Scene changes only on a sound image: a blur, shift or flash changes every zone.
        camera_ok = not (raw_bad or self._moved_raw or self._defocus_active
                         or self._timers[DEFOCUSED].since is not None)

        t = time.perf_counter()
        zone_states = self._check_zones(small_bgr, boxes, frame_bgr, now, camera_ok, alerts)
        timings["scene"] = _ms(t)
        if camera_ok and self._ref_small is None and not len(boxes):
            self._ref_small = small.astype(np.float32)  # no reference: the first sound frame
        timings["total"] = _ms(t_start)
        return HealthReport(self.camera_id, now, tuple(faults), tuple(alerts), zone_states,
                            dict(self._measures), timings,
                            picture_changed=self._freeze.really_changed,
                            analysis_bgr=small_bgr)

    def _due(self, now: float) -> bool:
        """Whether the moved check (the costliest) runs on this frame."""
        if self._last_moved is not None and now - self._last_moved + 1e-9 < \
                self.config.moved_interval_s:
            return False
        self._last_moved = now
        return True

    def _check_blinded(self, small: np.ndarray, now: float) -> Fault | None:
        cfg = self.config
        mean, std = (float(v[0, 0]) for v in cv2.meanStdDev(small))
        saturated = np.count_nonzero(small >= cfg.saturated_level) / small.size
        self._measures.update(brightness=mean, contrast=std, saturated=saturated)
        reason = ""
        if mean < cfg.dark_mean:
            reason = (f"too dark: mean brightness {mean:.0f} < {cfg.dark_mean:g} of 255 "
                      "(lens covered or light off?)")
        elif saturated > cfg.overexposed_fraction:
            reason = (f"overexposed: {100 * saturated:.0f} % of the image saturated "
                      f"(limit {100 * cfg.overexposed_fraction:.0f} %)")
        elif std < cfg.covered_contrast:
            reason = (f"covered: contrast {std:.1f} < {cfg.covered_contrast:g} grey levels "
                      "(something in front of the lens?)")
        held = self._timers[BLINDED].update(bool(reason), now)
        if reason and held >= cfg.blinded_after_s:
            return Fault(BLINDED, f"{self.camera_id}: {reason}", True, self.camera_id)
        return None

    def _check_frozen(self, small: np.ndarray, now: float) -> Fault | None:
        freeze = self._freeze
        if self._prev_small is None:
            freeze.restart(now)
            return None
        diff = float(cv2.norm(small, self._prev_small, cv2.NORM_L1)) / small.size
        threshold = freeze.step(diff, now, self.config)
        self._measures.update(frame_diff=diff, frozen_threshold=threshold)
        if not freeze.active:
            return None
        if freeze.changing:
            reason = (f"image was frozen, picture changing again for "
                      f"{now - freeze.run_since:.1f} s, not yet {self.config.frozen_clear_s:g} "
                      "s like a live camera's")
        else:
            reason = (f"image unchanged for {now - freeze.picture_time:.1f} s (mean difference "
                      f"{diff:.2f} < {threshold:.2g} grey levels, the camera's own noise)")
        return Fault(FROZEN, f"{self.camera_id}: {reason}", True, self.camera_id)

    def _check_defocus(self, small: np.ndarray, frame_bgr: np.ndarray,
                       now: float) -> list[Alert]:
        cfg = self.config
        sharp = sharpness(small)
        if self._ref_sharpness is None:  # no reference: the median of the first sound frames
            self._sharp_samples.append(sharp)
            if len(self._sharp_samples) >= cfg.baseline_frames:
                self._ref_sharpness = float(np.median(self._sharp_samples))
            return []
        ratio = sharp / max(self._ref_sharpness, 1e-6)
        self._measures["sharpness_ratio"] = ratio
        low_for = self._timers[DEFOCUSED].update(ratio < cfg.defocus_ratio, now)
        ok_for = self._timers["focus_ok"].update(ratio >= cfg.defocus_ratio, now)
        if not self._defocus_active and low_for >= cfg.defocus_after_s:
            self._defocus_active = True
            self._defocus_reason = (f"{self.camera_id}: image blurred: sharpness "
                                    f"{100 * ratio:.0f} % of the reference (limit "
                                    f"{100 * cfg.defocus_ratio:.0f} %); check focus and lens")
            snapshot = encode_jpeg(frame_bgr, cfg.snapshot_max_width, cfg.snapshot_quality)
            return [Alert(DEFOCUSED, "warning", self._defocus_reason, self.camera_id, now,
                          snapshot, {"sharpness_ratio": round(ratio, 3)})]
        if self._defocus_active and ok_for >= cfg.clear_time_s:
            self._defocus_active = False
            return [Alert(DEFOCUSED_CLEARED, "info", f"{self.camera_id}: image sharp again "
                          f"({100 * ratio:.0f} % of the reference)", self.camera_id, now, None,
                          {"sharpness_ratio": round(ratio, 3)})]
        return []

    def _check_moved(self, small: np.ndarray, boxes: np.ndarray) -> None:
        """Phase correlation of the view against the reference; sets the raw state the MOVED
        timer follows."""
        cfg = self.config
        current = small.astype(np.float32)
        window = self._window
        persons = self._small_boxes(boxes, margin=False)
        if persons:
            # persons are not part of the view: both images weighed 0 there, with soft edges
            # (a sharp edge at the same place in both would itself match at no shift). The
            # reference pasted into the frame there (as before) matched itself at no shift,
            # and a person in the middle of the view, where the window weighs most, hid a
            # camera knocked 40 px aside (tests/test_health_1080p.py)
            hole = np.zeros_like(window)
            for x1, y1, x2, y2 in persons:
                hole[y1:y2, x1:x2] = 1.0
            window = window * (1.0 - np.minimum(cv2.GaussianBlur(hole, (0, 0), 1.5) * 2, 1.0))
        # copy: OpenCV 5.0's phaseCorrelate multiplies its inputs by the window in place
        (dx, dy), match = cv2.phaseCorrelate(self._ref_small.copy(), current, window)
        shift = math.hypot(dx, dy) * self._scale
        self._measures.update(shift_px=shift, match=float(match))
        if match < cfg.moved_min_match:
            self._moved_raw = True
            self._moved_reason = (f"{self.camera_id}: view does not match the reference (match "
                                  f"{match:.2f} < {cfg.moved_min_match:g}): camera moved, turned "
                                  "or view blocked")
        elif shift > cfg.moved_px:
            self._moved_raw = True
            self._moved_reason = (f"{self.camera_id}: view shifted by {shift:.0f} px (dx "
                                  f"{round(dx * self._scale)}, dy {round(dy * self._scale)}; "
                                  f"limit {cfg.moved_px:g} px) against the reference")
        else:
            self._moved_raw = False

    def _small_boxes(self, boxes: np.ndarray, margin: bool) -> list[tuple[int, int, int, int]]:
        """Person boxes in analysis pixels, clipped; with ``margin`` grown by person_margin."""
        sw, sh = self._small_size
        out = []
        for x1, y1, x2, y2 in boxes / self._scale:
            if margin:
                mx = (x2 - x1) * self.config.person_margin + 1
                my = (y2 - y1) * self.config.person_margin + 1
                x1, y1, x2, y2 = x1 - mx, y1 - my, x2 + mx, y2 + my
            bx1, by1 = max(0, math.floor(x1)), max(0, math.floor(y1))
            bx2, by2 = min(sw, math.ceil(x2)), min(sh, math.ceil(y2))
            if bx2 > bx1 and by2 > by1:
                out.append((bx1, by1, bx2, by2))
        return out

    def _check_zones(self, small_bgr: np.ndarray, boxes: np.ndarray, frame_bgr: np.ndarray,
                     now: float, camera_ok: bool, alerts: list[Alert]) -> tuple[ZoneStatus, ...]:
        """The watch zones' scene-change check (monitor/health/scene.py) on this frame."""
        if not self._watch.zones:
            return ()
        return self._watch.check(small_bgr, self._small_boxes(boxes, margin=True), frame_bgr,
                                 now, self._dt, camera_ok, alerts)



def _ms(start: float) -> float:
    return (time.perf_counter() - start) * 1e3
