"""The one error type of the geometry functions."""

from __future__ import annotations


class GeometryError(ValueError):
    """A geometric input cannot be used (degenerate polygon, singular homography, ...)."""

