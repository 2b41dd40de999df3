"""The health checks' thresholds (``HealthConfig``, the ``health`` config section) and the names
of the faults and alerts they produce."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field

from monitor.schema import Float, Int, NonNegative, Seconds, section

# Fault and alert names the health checks produce.
LOST, FROZEN, BLINDED, MOVED, DEFOCUSED = (
    "camera_lost", "camera_frozen", "camera_blinded", "camera_moved", "camera_defocused")
SCENE_CHANGE, SCENE_CHANGE_CLEARED = "scene_change", "scene_change_cleared"
DEFOCUSED_CLEARED = "camera_defocused_cleared"
# keys of timings_ms
CHECKS = ("prepare", "blinded", "envelope", "frozen", "defocus", "moved", "scene")


def _within(lo: float, hi: float) -> Any:
    return Field(ge=lo, le=hi)



@section("health")
class HealthConfig:
    """Thresholds of the health checks. Grey levels are 0..255; areas and shifts are in pixels
    of the camera's full-resolution frame; times in seconds. Every value is finite and >= 0."""

    # px width of the grey image the checks use (height keeps aspect)
    analysis_width: Annotated[Int, _within(64, 1280)] = 320
    lost_after_s: NonNegative = 1.0  # no frame for this long: camera_lost
    # a frame differs from the one before "beyond the noise" when the mean |difference|
    # (grey levels) reaches this, and this share of the camera's own live difference (the
    # 10th percentile of its last 300 live frames; ``frozen_noise_share``) ...
    frozen_diff: NonNegative = 0.3
    frozen_noise_share: Annotated[Float, _within(0.0, 1.0)] = 0.25
    # ... the picture really changed when two differences in a row did (a codec's keyframe
    # in a repeated picture is one jump); no real change for this long: camera_frozen ...
    frozen_after_s: NonNegative = 1.0
    # ... which ends once the picture has changed like a live camera's (every frame) this long
    frozen_clear_s: NonNegative = 0.5
    dark_mean: Annotated[Float, _within(0.0, 254.0)] = 25.0  # mean below this: blinded, dark
    # a pixel at or above this grey level is saturated ...
    saturated_level: Annotated[Int, _within(1, 255)] = 250
    # ... and more than this fraction saturated: overexposed
    overexposed_fraction: Annotated[Float, _within(0.01, 1.0)] = 0.5
    covered_contrast: NonNegative = 6.0  # std of grey levels below this: blinded, covered
    blinded_after_s: NonNegative = 0.0  # 0: blinded at the first such frame
    # sharpness below this fraction of the reference's ...
    # (sharpness: variance of the Laplacian / variance of the image, on the analysis image)
    defocus_ratio: Annotated[Float, _within(0.01, 1.0)] = 0.45
    defocus_after_s: NonNegative = 2.0  # ... for this long: camera_defocused (warning)
    moved_px: NonNegative = 8.0  # view shifted more than this against the reference ...
    # ... or phase-correlation peak below this (view replaced) ...
    moved_min_match: Annotated[Float, _within(0.0, 1.0)] = 0.2
    moved_after_s: NonNegative = 0.5  # ... for this long: camera_moved
    moved_interval_s: NonNegative = 0.25  # run the moved check (0.6 ms) at most this often
    # levels (any colour channel) a pixel must differ from the zone's background, beyond its
    # 3x3 neighbourhood and after matching the lighting
    scene_diff: Annotated[Float, _within(1.0, 255.0)] = 25.0
    scene_min_area_px: NonNegative = 400.0  # changed area (px²) that counts (20x20 px)
    persist_time_s: NonNegative = 3.0  # a change must last this long to raise scene_change
    clear_time_s: NonNegative = 2.0  # warnings clear after the scene is normal this long
    learn_time_s: Seconds = 10.0  # time constant of the background's adaptation (lighting)
    # person boxes grow by this fraction of their size on each side
    person_margin: Annotated[Float, _within(0.0, 2.0)] = 0.15
    # zone less visible than this (persons): no decision
    min_visible_fraction: Annotated[Float, _within(0.01, 1.0)] = 0.3
    # frames for the sharpness baseline when there is no reference
    baseline_frames: Annotated[Int, _within(1, 1000)] = 15
    # px; snapshots are scaled down to at most this width
    snapshot_max_width: Annotated[Int, _within(64, 8192)] = 1280
    snapshot_quality: Annotated[Int, _within(1, 100)] = 85  # JPEG quality 1..100
    # the detector's operating envelope (docs/health.md): measured at start on the self-test
    # figure, the limits within which its recall is at least this ...
    envelope_min_recall: Annotated[Float, _within(0.5, 1.0)] = 0.9
    # ... and a warning when an image measure comes within this fraction of a limit
    envelope_margin: Annotated[Float, _within(0.0, 1.0)] = 0.15
    # the in-place check (monitor/detector/inplace.py) runs this often per camera
    inplace_period_s: Annotated[Float, _within(0.5, 60.0)] = 3.0

