"""Alerts of STOP faults: a critical alert (with a snapshot when there is a frame) when a fault
appears and an info alert when it clears, so a maintenance engineer learns that a camera went
dark, not only the robot controller. Also the one-line text of a stage's exception."""

from __future__ import annotations

import cv2
import numpy as np

from monitor.types import Alert, Fault

# Faults that are expected at start-up or say nothing a person must act on.
# (zones_applying: the zones_applied alert already says it, with operator and hashes)
QUIET_FAULTS = frozenset({"camera_waiting", "zones_applying"})


def snapshot(image: np.ndarray | None, max_width: int = 1280) -> bytes | None:
    """A JPEG of the frame (scaled to at most ``max_width``), or None."""
    if image is None or image.ndim != 3:
        return None
    if image.shape[1] > max_width:
        scale = max_width / image.shape[1]
        image = cv2.resize(image, (max_width, round(image.shape[0] * scale)),
                           interpolation=cv2.INTER_AREA)
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
    return jpeg.tobytes() if ok else None


def one_line(exc: BaseException) -> str:
    """A stage's exception as one line (its type and the first line of its text)."""
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text.splitlines()[0]}" if text else type(exc).__name__


class FaultAlerts:
    """The STOP faults active at the previous decision, to alert their appearance and end."""

    def __init__(self) -> None:
        self._active: dict[tuple[str, str], Fault] = {}  # (name, source) -> fault

    def alerts(self, faults: tuple[Fault, ...], detector_error: str | None, now: float,
               image: np.ndarray | None) -> tuple[Alert, ...]:
        """The alerts of the faults that appeared (with a snapshot of ``image``) or cleared
        since the previous decision."""
        active = {(f.name, f.source): f for f in faults if f.stop and f.name not in QUIET_FAULTS}
        if detector_error:
            active[("detector_error", "detector")] = Fault("detector_error", detector_error,
                                                           True, "detector")
        alerts = []
        for key, fault in active.items():
            if key not in self._active:
                alerts.append(Alert(fault.name, "critical", fault.reason, fault.source, now,
                                    snapshot_jpeg=snapshot(image),
                                    details={"fault": fault.name, "stop": True}))
        for key, fault in self._active.items():
            if key not in active:
                alerts.append(Alert(f"{fault.name}_cleared", "info",
                                    f"{fault.name} cleared: {fault.reason}", fault.source, now,
                                    details={"fault": fault.name}))
        self._active = active
        return tuple(alerts)
