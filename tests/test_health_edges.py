"""The camera health checks at their limits: exact thresholds, the measures they report, the
fault each raises and its words (found by mutation testing of monitor/health/camera.py's fault
decisions). Frames are 320x240 with a 320-px analysis image, so pixel values are exact."""

from __future__ import annotations

import numpy as np
import pytest

from monitor.health import BLINDED, FROZEN, LOST, CameraHealth, HealthConfig
from monitor.types import Fault

W, H = 320, 240


def health(**config) -> CameraHealth:
    return CameraHealth(HealthConfig(analysis_width=W, **config), "cam0")


def grey(values: np.ndarray) -> np.ndarray:
    """A BGR frame whose grey image is exactly ``values`` (H, W) uint8."""
    return np.repeat(values.astype(np.uint8)[:, :, None], 3, axis=2)


def textured(mean: int = 100, half_spread: int = 20) -> np.ndarray:
    """Columns alternating mean - s and mean + s: mean exactly ``mean``, std exactly s."""
    v = np.full((H, W), mean - half_spread, np.int32)
    v[:, 1::2] = mean + half_spread
    return v


def test_before_any_frame_the_camera_is_lost_with_a_stop_fault():
    assert health().check_lost(5.0) == Fault(LOST, "cam0: no frame received yet", True, "cam0")


def test_lost_only_after_more_than_lost_after_s():
    h = health(lost_after_s=1.0)
    h.check(grey(textured()), 10.0)
    assert h.check_lost(11.0) is None  # exactly the limit: not yet
    assert h.check_lost(11.25) == Fault(LOST, "cam0: no frame for 1.2 s (limit 1 s)", True,
                                        "cam0")


def test_the_measures_of_a_frame():
    h = health()
    values = textured(100, 20)
    values[:48, :] = 255  # 20 % of the pixels saturated
    report = h.check(grey(values), 0.0)
    expected_mean = 0.2 * 255 + 0.8 * 100
    assert report.measures["brightness"] == pytest.approx(expected_mean, abs=1e-6)
    assert report.measures["saturated"] == pytest.approx(0.2)
    assert report.measures["contrast"] > 20
    second = h.check(grey(values + (values < 255)), 0.1)  # all but the saturated rows +1
    assert second.measures["frame_diff"] == pytest.approx(0.8)


@pytest.mark.parametrize(("level", "blinded"), [(25, False), (24, True)])
def test_too_dark_only_below_dark_mean(level, blinded):
    report = health(dark_mean=25.0, covered_contrast=0.0).check(grey(np.full((H, W), level)),
                                                                0.0)
    faults = [f for f in report.faults if f.name == BLINDED]
    if not blinded:
        assert faults == []
    else:
        assert faults == [Fault(BLINDED, "cam0: too dark: mean brightness 24 < 25 of 255 "
                                "(lens covered or light off?)", True, "cam0")]


@pytest.mark.parametrize(("rows", "blinded"), [(144, False), (168, True)])
def test_overexposed_counts_pixels_at_the_saturated_level(rows, blinded):
    values = textured(100, 20)
    values[:rows, :] = 250  # exactly the saturated level: counts as saturated
    report = health(saturated_level=250, overexposed_fraction=0.6).check(grey(values), 0.0)
    faults = [f for f in report.faults if f.name == BLINDED]
    if not blinded:  # exactly 60 %: not more than the limit
        assert faults == []
    else:
        assert faults == [Fault(BLINDED, "cam0: overexposed: 70 % of the image saturated "
                                "(limit 60 %)", True, "cam0")]


@pytest.mark.parametrize(("spread", "blinded"), [(6, False), (5, True)])
def test_covered_only_below_the_contrast_limit(spread, blinded):
    report = health(covered_contrast=6.0).check(grey(textured(100, spread)), 0.0)
    faults = [f for f in report.faults if f.name == BLINDED]
    if not blinded:
        assert faults == []
    else:
        assert faults == [Fault(BLINDED, "cam0: covered: contrast 5.0 < 6 grey levels "
                                "(something in front of the lens?)", True, "cam0")]


@pytest.mark.parametrize(("changed_rows", "frozen"), [(72, False), (48, True)])
def test_frozen_only_below_the_difference_limit(changed_rows, frozen):
    h = health(frozen_diff=0.3, frozen_after_s=0.0)
    first = textured(100, 20)
    second = first.copy()
    second[:changed_rows, :] += 1  # 72 of 240 rows: mean difference exactly 0.3
    h.check(grey(first), 0.0)
    report = h.check(grey(second), 0.1)
    faults = [f for f in report.faults if f.name == FROZEN]
    assert report.measures["frame_diff"] == pytest.approx(changed_rows / H)
    assert bool(faults) is frozen
    if frozen:
        assert faults[0].stop and faults[0].source == "cam0"
        assert "mean difference 0.20 < 0.3 grey levels" in faults[0].reason


def test_frozen_is_judged_against_the_cameras_own_noise():
    """A noisy camera (live frames differ by about 9 grey levels) whose picture then repeats
    with a re-encoding's flicker of about 1.3 grey levels every frame: far above frozen_diff,
    far below the camera's own noise. Frozen 1 s after its last live frame; judged by
    frozen_diff alone (frozen_noise_share 0) the flicker looks live and it never is."""
    rng = np.random.default_rng(0)
    base = textured(120, 30).astype(np.int16)

    def frame(sigma: float) -> np.ndarray:
        noisy = base + np.rint(rng.normal(0.0, sigma, base.shape)).astype(np.int16)
        return grey(np.clip(noisy, 0, 255).astype(np.uint8))

    still = frame(0.0)
    for share, frozen in ((0.25, True), (0.0, False)):
        h = health(frozen_noise_share=share)
        reports = [h.check(frame(8.0), k / 10) for k in range(30)]  # 3 s live at 10 fps
        reports += [h.check(frame(1.2) if k % 2 else still, 3.0 + k / 10)
                    for k in range(1, 21)]
        flicker = reports[-1].measures["frame_diff"]
        assert 0.3 < flicker < 2.0
        assert reports[29].measures["frozen_threshold"] == (
            pytest.approx(2.0, abs=0.6) if share else 0.3)
        faults = [any(f.name == FROZEN for f in r.faults) for r in reports]
        if frozen:  # the last live difference is 3.1 s (into the first flicker frame)
            assert reports[faults.index(True)].time == pytest.approx(4.1)
            assert all(faults[faults.index(True):])
        else:
            assert not any(faults)
