"""Frame sources: cameras, video files, images, RTSP/HTTP streams and the synthetic demo scene.

Two ways to get frames:

- Replay reads a file frame by frame with :class:`VideoFileReader`; ``capture_time`` is the
  video's own clock (seconds from the container's timestamps), so the same file always gives the
  same times.
- The live service wraps any source in a :class:`LatestFrameGrabber`: a thread that keeps only the
  newest frame, stamps it with the monotonic clock at grab time, counts the frames nobody took,
  and reconnects with a bounded exponential backoff after a loss. Its ``connected``,
  ``last_frame_time`` and ``last_error`` let health and policy STOP on a lost camera.

Sources are made from a spec string by :func:`open_source` (``0``, ``video.mp4``, ``still.png``,
``rtsp://...``, ``http://...``, ``synthetic:demo``); the kinds are listed in ``SOURCE_KINDS``.

Images are BGR ``uint8`` arrays of shape (height, width, 3); sizes are ``(width, height)`` in
pixels. Every error a user can fix is an :class:`~monitor.errors.InputError` with a one-line
message naming the source and the fault.

Modules: ``base`` (the frame, the source protocol, source kinds, frame times, the backoff),
``video`` (files), ``sources`` (images, cameras, streams, the synthetic scene, pacing,
``open_source``), ``grabber`` (the live newest-frame grabber).

May import: ``monitor.scene`` (the synthetic demo source) and the bottom layer.
"""

from monitor.frames.base import (
    IMAGE_SUFFIXES,
    URL_SCHEMES,
    Backoff,
    Clock,
    Frame,
    FrameSource,
    Size,
    TruncatedVideoError,
    check_frame_size,
    frame_time_s,
    one_line,
    redact_url,
    source_kind,
)
from monitor.frames.grabber import GrabberStatus, LatestFrameGrabber
from monitor.frames.sources import (
    PACEABLE_KINDS,
    SOURCE_KINDS,
    SYNTHETIC_SCENES,
    CameraSource,
    ImageSource,
    PacedSource,
    SourceOptions,
    StreamSource,
    SyntheticSource,
    open_source,
)
from monitor.frames.video import VideoFileReader

__all__ = [
    "IMAGE_SUFFIXES", "PACEABLE_KINDS", "SOURCE_KINDS", "SYNTHETIC_SCENES", "URL_SCHEMES",
    "Backoff", "CameraSource", "Clock", "Frame", "FrameSource", "GrabberStatus", "ImageSource",
    "LatestFrameGrabber", "PacedSource", "Size", "SourceOptions", "StreamSource",
    "SyntheticSource", "TruncatedVideoError", "VideoFileReader", "check_frame_size",
    "frame_time_s", "one_line", "open_source", "redact_url", "source_kind",
]
