"""Scene changes in the watch zones of one camera: a lasting change against each zone's
background raises ``scene_change`` (a warning with a JPEG snapshot that outlines the change) and,
once the zone is normal again, ``scene_change_cleared``.

Works on the analysis image of ``CameraHealth`` (monitor/health/camera.py), which decides when the
image is sound enough to judge and passes the persons' boxes: their pixels say nothing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from monitor.errors import ConfigError
from monitor.health.config import SCENE_CHANGE, SCENE_CHANGE_CLEARED, HealthConfig
from monitor.health.draw import encode_jpeg
from monitor.health.report import ZoneStatus
from monitor.types import Alert


@dataclass
class _Zone:
    """A watch zone on the analysis image: crop bounds, polygon mask and learned background."""

    zone_id: str
    polygon_px: np.ndarray
    x0: int
    y0: int
    x1: int
    y1: int
    mask: np.ndarray  # bool, crop-sized: inside the polygon
    background: np.ndarray | None = None  # float32 BGR, crop-sized
    state: str = "learning"
    since: float = 0.0  # when the current pending/clearing state began
    changed: np.ndarray | None = None  # bool mask of the last decision's changed pixels


class WatchZones:
    """The watch zones of one camera: their geometry on the analysis image, learned backgrounds
    and alert states. ``watch_zones`` are ``(zone_id, polygon_px)`` pairs, polygons (K, 2) in
    full-resolution pixels of the camera."""

    def __init__(self, config: HealthConfig, camera_id: str,
                 watch_zones: Sequence[tuple[str, np.ndarray]] = ()):
        self.config = config
        self.camera_id = camera_id
        self._zone_specs = [(str(zid), np.asarray(poly, np.float64).reshape(-1, 2))
                            for zid, poly in watch_zones]
        for zid, poly in self._zone_specs:
            if len(poly) < 3:
                raise ConfigError(f"zone {zid}: a watch polygon needs at least 3 points")
        self.zones: list[_Zone] = []  # empty until ``prepare``
        self._scale = 1.0  # full-resolution px per analysis px

    def clear(self) -> None:
        """Forget geometry, backgrounds and states (a new reference); ``prepare`` rebuilds them."""
        self.zones = []

    def prepare(self, width: int, height: int, small_size: tuple[int, int], scale: float,
                ref_small_bgr: np.ndarray | None) -> None:
        """Lay the zones onto the analysis image (``small_size`` of a ``width`` x ``height``
        frame, ``scale`` full-resolution px per analysis px); with a reference (float32 BGR at
        the analysis size) it is each zone's background."""
        sw, sh = small_size
        self._scale = scale
        self.zones = []
        for zid, poly in self._zone_specs:
            small_poly = poly / self._scale
            # one pixel of margin: the jitter tolerance compares with neighbours outside too
            x0, y0 = np.floor(small_poly.min(axis=0)).astype(int) - 1
            x1, y1 = np.ceil(small_poly.max(axis=0)).astype(int) + 2
            x0, y0, x1, y1 = max(0, x0), max(0, y0), min(sw, x1), min(sh, y1)
            if x1 - x0 < 2 or y1 - y0 < 2:
                raise ConfigError(f"zone {zid}: watch polygon lies outside the {width}x{height} "
                                  f"image of camera {self.camera_id}")
            mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
            pts = np.round((small_poly - (x0, y0)) * 8).astype(np.int32)  # 3 bits sub-pixel
            cv2.fillPoly(mask, [pts], 1, cv2.LINE_8, shift=3)
            zone = _Zone(zid, poly, int(x0), int(y0), int(x1), int(y1), mask.astype(bool))
            if ref_small_bgr is not None:
                zone.background = ref_small_bgr[y0:y1, x0:x1].copy()
                zone.state = "normal"
            self.zones.append(zone)

    def check(self, small_bgr: np.ndarray, person_boxes: Sequence[tuple[int, int, int, int]],
              frame_bgr: np.ndarray, now: float, dt: float, camera_ok: bool,
              alerts: list[Alert]) -> tuple[ZoneStatus, ...]:
        """Check the zones on one frame: ``small_bgr`` is the analysis image, ``person_boxes``
        the persons (analysis px, grown by ``person_margin``), ``dt`` the seconds since the
        previous frame (the learning rate). Raised alerts are appended to ``alerts``; without
        ``camera_ok`` (an unsound image) nothing is decided."""
        if not self.zones:
            return ()
        cfg = self.config
        out = []
        for zone in self.zones:
            if not camera_ok:
                if zone.state == "pending":  # the image is unsound: start over when it is back
                    zone.state = "normal"
                out.append(ZoneStatus(zone.zone_id, zone.state))
                continue
            # colour, not grey: a magenta jacket and a grey shelf can have the same grey level
            crop = small_bgr[zone.y0:zone.y1, zone.x0:zone.x1].astype(np.float32)
            free = zone.mask.copy()
            occupied = False
            for x1, y1, x2, y2 in person_boxes:
                cx1, cy1 = max(x1 - zone.x0, 0), max(y1 - zone.y0, 0)
                cx2, cy2 = min(x2 - zone.x0, free.shape[1]), min(y2 - zone.y0, free.shape[0])
                if cx2 > cx1 and cy2 > cy1 and zone.mask[cy1:cy2, cx1:cx2].any():
                    free[cy1:cy2, cx1:cx2] = False
                    occupied = True
            if zone.background is None:
                if not occupied:  # no reference: learn from the first frame without persons
                    zone.background = crop.copy()
                    zone.state = "normal"
                out.append(ZoneStatus(zone.zone_id, zone.state))
                continue
            n_free = int(np.count_nonzero(free))
            if n_free < cfg.min_visible_fraction * np.count_nonzero(zone.mask):
                out.append(self._zone_status(zone, 0.0))  # hidden by persons: no decision
                continue
            changed = self._changed_pixels(zone, crop, free)
            area = float(np.count_nonzero(changed)) * self._scale ** 2
            if not occupied:  # learn (lighting drift) only where nothing changed
                keep = (~changed).view(np.uint8)
                cv2.accumulateWeighted(crop, zone.background,
                                       min(1.0, dt / cfg.learn_time_s), keep)
            alert = self._zone_step(zone, area >= cfg.scene_min_area_px, changed, area,
                                    frame_bgr, now)
            if alert is not None:
                alerts.append(alert)
            out.append(self._zone_status(zone, area))
        return tuple(out)

    def _changed_pixels(self, zone: _Zone, crop: np.ndarray, free: np.ndarray) -> np.ndarray:
        """Pixels where a colour channel is below the darkest or above the brightest background
        pixel of its 3x3 neighbourhood by ``scene_diff``, once the zone's lighting is matched to
        the background (``_lighting``): tolerant to a pixel of jitter and to lighting changes,
        yet a thin cable shows. Pixels clipped at black or white in both say nothing."""
        bg = zone.background
        thr = self.config.scene_diff
        visible = free.ravel()  # np.compress: 5x cheaper than boolean indexing here
        gain, offset = _lighting(np.compress(visible, crop.reshape(-1, 3), axis=0).ravel(),
                                 np.compress(visible, bg.reshape(-1, 3), axis=0).ravel(), thr)
        level = cv2.addWeighted(crop, 1.0 / gain, crop, 0.0, -offset / gain)
        kernel = np.ones((3, 3), np.uint8)
        excess = np.maximum(cv2.erode(bg, kernel) - level, level - cv2.dilate(bg, kernel))
        if crop.max() >= 250 or crop.min() <= 5:  # rare: only then look for clipped pixels
            predicted = gain * bg + offset
            excess[(crop >= 250) & (predicted >= 250 - thr)
                   | (crop <= 5) & (predicted <= 5 + thr)] = 0.0
        # channel by channel: numpy's reductions over a last axis of 3 are slow
        excess = np.maximum(np.maximum(excess[..., 0], excess[..., 1]), excess[..., 2])
        return free & (excess > thr)

    def _zone_step(self, zone: _Zone, changed_now: bool, changed: np.ndarray, area: float,
                   frame_bgr: np.ndarray, now: float) -> Alert | None:
        """normal -> pending -> active -> clearing -> normal, with the persist/clear times."""
        cfg = self.config
        if changed_now:
            zone.changed = changed
        if zone.state == "normal" and changed_now:
            zone.state, zone.since = "pending", now
        elif zone.state == "pending" and not changed_now:
            zone.state = "normal"
        elif zone.state == "clearing" and changed_now:
            zone.state = "active"
        elif zone.state == "active" and not changed_now:
            zone.state, zone.since = "clearing", now
        if zone.state == "pending" and now - zone.since + 1e-9 >= cfg.persist_time_s:
            zone.state = "active"
            box = self._change_box(zone)
            message = (f"{self.camera_id}: scene changed in watch zone {zone.zone_id} for "
                       f"{now - zone.since:.1f} s ({area:.0f} px² at {box})")
            return Alert(SCENE_CHANGE, "warning", message, self.camera_id, now,
                         self._snapshot(frame_bgr, zone),
                         {"zone": zone.zone_id, "box_px": list(box), "area_px": round(area)})
        if zone.state == "clearing" and now - zone.since + 1e-9 >= cfg.clear_time_s:
            zone.state = "normal"
            zone.changed = None
            return Alert(SCENE_CHANGE_CLEARED, "info", f"{self.camera_id}: watch zone "
                         f"{zone.zone_id} back to normal", self.camera_id, now, None,
                         {"zone": zone.zone_id})
        return None

    def _zone_status(self, zone: _Zone, area: float) -> ZoneStatus:
        box = self._change_box(zone) if zone.state != "normal" and zone.changed is not None \
            else None
        return ZoneStatus(zone.zone_id, zone.state, area, box)

    def _change_box(self, zone: _Zone) -> tuple[int, int, int, int]:
        """Bounding box (full-resolution px, x2/y2 exclusive) of the zone's changed pixels."""
        ys, xs = np.nonzero(zone.changed)
        if len(xs) == 0:
            return int(zone.x0 * self._scale), int(zone.y0 * self._scale), \
                int(zone.x1 * self._scale), int(zone.y1 * self._scale)
        s = self._scale
        return (int((zone.x0 + xs.min()) * s), int((zone.y0 + ys.min()) * s),
                math.ceil((zone.x0 + xs.max() + 1) * s),
                math.ceil((zone.y0 + ys.max() + 1) * s))

    def _snapshot(self, frame_bgr: np.ndarray, zone: _Zone) -> bytes:
        """JPEG of the frame with the zone (yellow) and each changed region (red) outlined."""
        image = frame_bgr.copy()
        cv2.polylines(image, [np.round(zone.polygon_px).astype(np.int32)], True,
                      (0, 220, 255), 2)
        s = self._scale
        pad = max(3, round(s))
        mask = zone.changed.astype(np.uint8) if zone.changed is not None else None
        if mask is not None and mask.any():
            n, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
            for x, y, w, h, _area in stats[1:n]:
                p1 = (int((zone.x0 + x) * s) - pad, int((zone.y0 + y) * s) - pad)
                p2 = (int((zone.x0 + x + w) * s) + pad, int((zone.y0 + y + h) * s) + pad)
                cv2.rectangle(image, p1, p2, (0, 0, 255), 3)
        cv2.putText(image, f"{self.camera_id}: scene change in watch zone {zone.zone_id}",
                    (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 255), 2)
        return encode_jpeg(image, self.config.snapshot_max_width, self.config.snapshot_quality)



def _lighting(current: np.ndarray, background: np.ndarray, tolerance: float) -> tuple[float, float]:
    """Gain and offset that map background levels to current ones (current = gain * bg + offset),
    fitted by least squares on the pixels that a plain median offset already explains within
    2 * ``tolerance`` (so a changed region does not bend the fit) and that are not clipped."""
    if len(current) < 30:
        return 1.0, 0.0
    diff = current - background
    offset = _median(diff)
    use = (np.abs(diff - offset) < 2 * tolerance) & (current < 250) & (current > 5)
    if np.count_nonzero(use) < 30:
        return 1.0, offset
    x, y = background[use].astype(np.float64), current[use].astype(np.float64)
    n = len(x)
    x_mean, y_mean = x.sum() / n, y.sum() / n
    var = float(np.dot(x, x)) / n - x_mean * x_mean  # dot products: cheap on small arrays
    if var < 25.0:  # a flat zone: the gain is not defined, an offset does
        return 1.0, float(y_mean - x_mean)
    gain = min(max((float(np.dot(x, y)) / n - x_mean * y_mean) / var, 0.5), 2.0)
    return gain, float(y_mean - gain * x_mean)


def _median(values: np.ndarray) -> float:
    """Median (upper for even sizes) by np.partition: 5x cheaper than np.median on small arrays."""
    half = len(values) // 2
    return float(np.partition(values, half)[half])

