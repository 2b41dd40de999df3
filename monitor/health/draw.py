"""Drawing for the health checks: a report onto a frame (``draw_health``) and the JPEG encoding
of alert snapshots."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from monitor.errors import InputError
from monitor.health.report import HealthReport


def encode_jpeg(image: np.ndarray, max_width: int, quality: int) -> bytes:
    """JPEG of ``image``, scaled down to at most ``max_width`` px wide."""
    if image.shape[1] > max_width:
        scale = max_width / image.shape[1]
        image = cv2.resize(image, (max_width, round(image.shape[0] * scale)),
                           interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise InputError("health: JPEG encoding of a snapshot failed")
    return buf.tobytes()


# the watch zones' outline: COLOURS_BGR["watch"] of monitor/zones/draw.py (the zone preview's
# colour; not imported: health stays free of the zone package)
WATCH_BGR = (230, 160, 30)


def draw_health(image: np.ndarray, report: HealthReport,
                polygons_px: Sequence[tuple[str, np.ndarray]] = (), text_top: int = 30) -> None:
    """Draw a report onto a full-resolution BGR frame in place: watch zones (``WATCH_BGR``, the
    zone preview's watch colour), their changes (orange while pending, red when alerted) and
    the active faults as text from row ``text_top`` down."""
    states = {z.zone_id: z for z in report.zones}
    for zone_id, polygon in polygons_px:
        cv2.polylines(image, [np.round(polygon).astype(np.int32)], True, WATCH_BGR, 2)
        status = states.get(zone_id)
        if status is not None and status.box_px is not None and status.state != "normal":
            colour = (0, 0, 255) if status.state in ("active", "clearing") else (0, 140, 255)
            x1, y1, x2, y2 = status.box_px
            cv2.rectangle(image, (x1, y1), (x2 - 1, y2 - 1), colour, 3)
            cv2.putText(image, f"{zone_id}: {status.state}", (x1, max(12, y1 - 6)),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2)
    for k, fault in enumerate(report.faults):
        colour = (0, 0, 255) if fault.stop else (0, 140, 255)
        cv2.putText(image, f"{fault.name}: {fault.reason}"[:90], (10, text_top + 24 * k),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2)
