"""The tracker's declared precision and the pose noise it lets through (issue 29).

The pose checks compare two readings of the tool: consecutive samples (``monitor.pose.stream``,
``check_step``) and the ends of a speed window (``monitor.pose.tool_motion``, the reported rates
against the measured ones). Each reading carries the tracker's own noise, so even a tool at rest
shows a difference. With fixed allowances, an optical tracker with 1 degree of orientation noise
made 291 of 480 stationary samples a ``pose_implausible`` STOP. So the allowance comes from the
precision the tracker declares, the same figure the tool calibration's check replays
(``monitor zones calibrate-tool --tracker-noise-mm/--tracker-noise-deg``,
``geometry.calibration_quality.TrackerNoise``): one standard deviation per axis.

Two readings with noise sigma per axis differ by sigma * sqrt(2) per axis; the length of that
3-axis difference exceeds ``NOISE_SIGMAS`` times it with a chance of 1.3e-10 (chi
distribution, 3 degrees of freedom): at 400 Hz and two comparisons a sample, one false STOP in
about 330 eight-hour shifts from noise that is really as declared (with 5 instead of 7: one
every 1.3 minutes, with 6: one every 4.6 hours). A jump larger than that is no noise and still
trips the checks.
"""

from __future__ import annotations

import math
from typing import Annotated

from pydantic import Field

from monitor.schema import Float, section

# how many (sigma * sqrt(2)) the difference of two noisy readings may be long (see above)
NOISE_SIGMAS = 7.0


@section("tracker")
class TrackerConfig:
    """The tool tracker's declared precision, one standard deviation per axis (OTUS: 1 mm and
    1 degree). The upper bounds keep the checks meaningful: at 2 degrees a 30 degree jump
    between two samples is still refused, a 20 degree one no longer."""

    noise_mm: Annotated[Float, Field(gt=0, le=5.0)] = 1.0
    noise_deg: Annotated[Float, Field(gt=0, le=2.0)] = 1.0

    @property
    def span_m(self) -> float:
        """The largest distance two readings of a tool at rest may be apart (m)."""
        return noise_span(self.noise_mm / 1000.0)

    @property
    def span_rad(self) -> float:
        """The largest turn between two readings of a tool at rest (rad)."""
        return noise_span(math.radians(self.noise_deg))


def noise_span(sigma: float) -> float:
    """The largest difference of two readings whose noise is ``sigma`` per axis."""
    return NOISE_SIGMAS * math.sqrt(2.0) * sigma
