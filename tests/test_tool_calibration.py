"""Closed-loop tool calibration (AX = XB): tracker on the flange and tracker frame in the cell,
from synthetic flange/tracker pose pairs with the seed report's noise (±1 mm, ±1°)."""

from __future__ import annotations

import numpy as np
import pytest

from monitor import geometry as geo
from tests.tool_poses import MOUNT, REFERENCE, pose_pairs


def test_exact_pairs_give_the_mounting_and_the_frame_exactly():
    flange, tracker = pose_pairs(np.random.default_rng(0), 6, 0.0, 0.0)
    cal = geo.calibrate_tool(flange, tracker)
    np.testing.assert_allclose(cal.flange_T_tracker, MOUNT, atol=1e-9)
    np.testing.assert_allclose(cal.cell_T_reference, REFERENCE, atol=1e-9)
    assert cal.residual_mm.max() < 1e-6 and cal.residual_deg.max() < 1e-5


@pytest.mark.parametrize("seed", range(5))
def test_noise_like_the_report_recovers_the_offset_within_1_mm_and_0_2_deg(seed):
    flange, tracker = pose_pairs(np.random.default_rng(seed), 80, 1.0, 1.0)
    cal = geo.calibrate_tool(flange, tracker)
    err_mm = 1000 * np.linalg.norm(cal.flange_T_tracker[:3, 3] - MOUNT[:3, 3])
    err_deg = geo.rotation_angle_deg(cal.flange_T_tracker[:3, :3].T @ MOUNT[:3, :3])
    assert err_mm < 1.0
    assert err_deg < 0.2
    frame_mm = 1000 * np.linalg.norm(cal.cell_T_reference[:3, 3] - REFERENCE[:3, 3])
    assert frame_mm < 3.0
    # the residuals show the noise: about 1 mm and 1 deg per pose, not zero
    assert 0.2 < np.median(cal.residual_mm) < 5.0
    assert 0.2 < np.median(cal.residual_deg) < 3.0


def test_poses_turning_about_one_axis_are_refused():
    rng = np.random.default_rng(1)
    flange, tracker = [], []
    for k in range(6):
        a = geo.rigid(geo.rpy_to_matrix(0, 0, 20.0 * k), rng.uniform(0.3, 0.9, 3))
        flange.append(a)
        tracker.append(np.linalg.inv(REFERENCE) @ a @ MOUNT)
    with pytest.raises(geo.GeometryError, match="same axis"):
        geo.calibrate_tool(flange, tracker)
    with pytest.raises(geo.GeometryError, match="at least 3"):
        geo.calibrate_tool(flange[:2], tracker[:2])
    still = [flange[0]] * 4
    with pytest.raises(geo.GeometryError, match="hardly turn"):
        geo.calibrate_tool(still, [tracker[0]] * 4)


def test_rpy_round_trip():
    for rpy in [(10.0, -20.0, 170.0), (0.4, -0.6, 179.5), (-35.0, 80.0, -120.0)]:
        back = geo.matrix_to_rpy_deg(geo.rpy_to_matrix(*rpy))
        np.testing.assert_allclose(geo.rpy_to_matrix(*back), geo.rpy_to_matrix(*rpy), atol=1e-9)


def test_the_seed_quaternion_is_w_first():
    """The report writes [0.004 0.005 -0.002 -1] and says 180 deg about z: read as x, y, z, w it
    would be no rotation at all; read w-first (w, x, y, z) it is the 180 deg turn."""
    w, x, y, z = 0.004, 0.005, -0.002, -1.0
    as_w_first = geo.quaternion_to_matrix((x, y, z, w))
    assert geo.rotation_angle_deg(as_w_first) == pytest.approx(180, abs=1.0)
    assert abs(as_w_first[2, 2] - 1) < 1e-3  # about z
    as_xyzw = geo.quaternion_to_matrix((w, x, y, z))
    assert geo.rotation_angle_deg(as_xyzw) < 1.0
