"""Deskewing a scan with the vehicle's own motion (attitude + DVL over the scan): analytic motions, the gaps that
leave a scan as it is, and the runner's use of it."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import InputError
from semslam.geometry import RigidTransform, rotation_from_rpy
from semslam.pipeline import PipelineConfig
from semslam.pipeline.deskew import NavigationHistory, deskew_points, scan_motion

T_VS = RigidTransform.from_xyz_rpy((0.6, 0.0, 0.3), (0.0, 0.0, 0.0))  # the simulator's scanner mount


def vehicle_pose(t, v_body, yaw_rate, roll=0.0, pitch=0.0):
    """A vehicle turning at a constant rate while moving at a constant body velocity: (R_world_vehicle, p_world)."""
    yaw = yaw_rate * t
    R = rotation_from_rpy(roll, pitch, yaw)
    if abs(yaw_rate) < 1e-12:
        p = R @ v_body * t
    else:  # integral of Rz(w s) v ds (roll and pitch zero in the turning cases)
        vx, vy, vz = v_body
        s, c = np.sin(yaw), np.cos(yaw)
        p = np.array([(vx * s + vy * (c - 1.0)) / yaw_rate, (vx * (1.0 - c) + vy * s) / yaw_rate, vz * t])
    return R, p


def scan_of_static_points(world_pts, stamps, v_body, yaw_rate):
    """Each world point as the scanner saw it at its own stamp (the distorted scan)."""
    T = T_VS.matrix
    out = np.empty_like(world_pts)
    for i, (w, t) in enumerate(zip(world_pts, stamps)):
        R, p = vehicle_pose(t, v_body, yaw_rate)
        x_vehicle = R.T @ (w - p)
        out[i] = T[:3, :3].T @ (x_vehicle - T[:3, 3])
    return out


def navigation(t0, t1, v_body, yaw_rate, rate_att=50.0, rate_dvl=5.0):
    ta = np.arange(t0 - 1.0, t1 + 1.0, 1.0 / rate_att)
    rpy = np.column_stack([np.zeros_like(ta), np.zeros_like(ta), yaw_rate * ta])
    td = np.arange(t0 - 1.0, t1 + 1.0, 1.0 / rate_dvl)
    return ta, rpy, td, np.tile(v_body, (len(td), 1)), np.ones(len(td), bool)


@pytest.mark.parametrize("yaw_rate", [0.0, 0.5])
def test_deskewed_scan_of_a_static_scene_is_the_scene_seen_at_the_scan_end(yaw_rate):
    rng = np.random.default_rng(0)
    t0, t1 = 10.0, 10.0 + 1.0 / 3.0
    v_body = np.array([0.3, 0.02, -0.01])
    stamps = np.sort(rng.uniform(t0, t1, 400))
    R1, p1 = vehicle_pose(t1, v_body, yaw_rate)
    world = p1 + R1 @ np.array([0.6, 0.0, 0.3]) + rng.uniform([-1, -1, 1.2], [1, 1, 1.8], (400, 3))
    raw = scan_of_static_points(world, stamps, v_body, yaw_rate)
    truth = scan_of_static_points(world, np.full(400, t1), v_body, yaw_rate)
    motion = scan_motion(*navigation(t0, t1, v_body, yaw_rate), np.eye(3), t0, t1)
    out = deskew_points(raw, stamps, motion, T_VS, t1)
    assert np.max(np.linalg.norm(raw - truth, axis=1)) > 0.05  # the scan is distorted by centimetres
    np.testing.assert_allclose(out, truth, atol=2e-4)


def test_dvl_in_its_own_frame_is_turned_into_the_vehicle_frame():
    t0, t1 = 0.0, 0.3
    v_body = np.array([0.3, 0.0, 0.0])
    R_vd = rotation_from_rpy(0.0, 0.0, np.pi / 2)  # DVL mounted turned by 90 degrees
    ta, rpy, td, _, ok = navigation(t0, t1, v_body, 0.0)
    v_dvl = np.tile(R_vd.T @ v_body, (len(td), 1))
    motion = scan_motion(ta, rpy, td, v_dvl, ok, R_vd, t0, t1)
    np.testing.assert_allclose(motion.p_world_vehicle_m[-1], v_body * (t1 - t0), atol=1e-9)


def test_invalid_dvl_and_gaps_leave_the_scan_undeskewed():
    t0, t1 = 0.0, 0.3
    ta, rpy, td, v, ok = navigation(t0, t1, np.array([0.3, 0.0, 0.0]), 0.0)
    assert scan_motion(ta, rpy, td, v, np.zeros_like(ok), np.eye(3), t0, t1) is None  # no bottom lock
    assert scan_motion(ta[ta < -0.9], rpy[ta < -0.9], td, v, ok, np.eye(3), t0, t1) is None  # attitude gap > 1 s
    assert scan_motion(ta, rpy, td, v, ok, np.eye(3), t1, t0) is None  # reversed span
    assert scan_motion(ta, rpy, td, v, ok, np.eye(3), t0, float("nan")) is None
    v_nan = v.copy()
    v_nan[::2] = np.nan  # NaN velocities are skipped, the rest is enough
    assert scan_motion(ta, rpy, td, v_nan, ok, np.eye(3), t0, t1) is not None


def test_points_without_a_finite_stamp_are_left_as_they_are():
    t0, t1 = 0.0, 0.3
    motion = scan_motion(*navigation(t0, t1, np.array([0.3, 0.0, 0.0]), 0.2), np.eye(3), t0, t1)
    pts = np.array([[0.1, 0.2, 1.5], [0.3, -0.2, 1.4]])
    out = deskew_points(pts, np.array([np.nan, 0.0]), motion, T_VS, t1)
    np.testing.assert_array_equal(out[0], pts[0])
    assert np.linalg.norm(out[1] - pts[1]) > 0.05


def test_noisy_attitude_is_smoothed_over_the_scan():
    """A 1-degree white yaw noise at 20 Hz (the simulator's AHRS) would turn a point at 2 m by ~3 cm if the samples
    were interpolated; the smoothed motion keeps the deskewed points within a few millimetres."""
    rng = np.random.default_rng(4)
    t0, t1 = 5.0, 5.0 + 1.0 / 3.0
    v_body = np.array([0.3, 0.0, 0.0])
    ta, rpy, td, v, ok = navigation(t0, t1, v_body, 0.0, rate_att=20.0)
    rpy[:, 2] += np.radians(1.0) * rng.standard_normal(len(ta))
    stamps = np.linspace(t0, t1, 200)
    world = np.column_stack([np.linspace(-0.5, 0.5, 200), np.zeros(200), np.full(200, 2.0)]) + [0.6 + 0.3 * t1, 0, 0.3]
    raw = scan_of_static_points(world, stamps, v_body, 0.0)
    truth = scan_of_static_points(world, np.full(200, t1), v_body, 0.0)
    out = deskew_points(raw, stamps, scan_motion(ta, rpy, td, v, ok, np.eye(3), t0, t1), T_VS, t1)
    assert np.median(np.linalg.norm(out - truth, axis=1)) < 0.006


def test_a_turn_starting_within_the_window_is_followed_and_a_smooth_motion_keeps_the_cubic():
    """The yaw rate stepping from 0 to 54 deg/s mid-scan (the simulator's corners) under 1 deg of white AHRS noise at
    20 Hz: over 20 noise draws the kinked line's largest yaw error over the scan is below the cubic's in every draw,
    0.4 deg median against 3.4; a smooth motion (a cubic in time, the same noise) keeps the plain cubic fit exactly."""
    from semslam.pipeline.deskew import _smooth

    t0, t1 = 5.0, 5.0 + 1.0 / 3.0
    ta = np.arange(t0 - 0.5, t1 + 0.5, 0.05)
    grid = np.linspace(t0, t1, 34)
    tm = 0.5 * (t0 + t1)

    def yaw(t):
        return np.radians(54.0) * np.maximum(t - (t0 + 0.1), 0.0)

    def cubic(t, y, at):
        return np.polyval(np.polyfit(t, y, 3), at)

    rng = np.random.default_rng(11)
    kinked, plain = [], []
    for _ in range(20):
        noisy = yaw(ta) + np.radians(1.0) * rng.standard_normal(len(ta))
        kinked.append(np.abs(_smooth(ta - tm, noisy[:, None], grid - tm)[:, 0] - yaw(grid)).max())
        plain.append(np.abs(cubic(ta - tm, noisy, grid - tm) - yaw(grid)).max())
        smooth = 0.3 * (ta - tm) ** 3 + 0.2 * (ta - tm) + np.radians(1.0) * rng.standard_normal(len(ta))
        np.testing.assert_allclose(_smooth(ta - tm, smooth[:, None], grid - tm)[:, 0],
                                   cubic(ta - tm, smooth, grid - tm), rtol=0, atol=1e-12)
    assert all(k < p for k, p in zip(kinked, plain))
    assert np.degrees(np.median(kinked)) < 0.5 and np.degrees(np.median(plain)) > 3.0


def test_navigation_history_keeps_its_memory_and_builds_the_motion():
    h = NavigationHistory(memory_s=2.0)
    for t in np.arange(0.0, 10.0, 0.02):
        h.add_attitude(t, np.array([0.0, 0.0, 0.1 * t]))
    for t in np.arange(0.0, 10.0, 0.2):
        h.add_dvl(t, np.array([0.3, 0.0, 0.0]), True)
    assert 7.9 < h.attitude[0][0] <= h.attitude[-1][0] - 2.0 + 0.02 and 7.7 < h.dvl[0][0] <= h.dvl[-1][0] - 2.0 + 0.2
    m = h.motion(np.eye(3), 9.5, 9.8)
    assert m is not None and m.p_world_vehicle_m[-1][0] == pytest.approx(0.3 * 0.3 * np.cos(0.965), abs=0.01)
    assert h.motion(np.eye(3), 20.0, 20.3) is None  # nothing near


def test_deskew_setting_is_a_boolean():
    assert PipelineConfig().deskew is True
    with pytest.raises(InputError, match="deskew"):
        PipelineConfig(deskew="yes")


@pytest.mark.parametrize("bad", [-0.1, 1.5, True, "0.5", float("nan")])
def test_deskew_lookahead_is_seconds_from_zero_to_one(bad):
    assert PipelineConfig().deskew_lookahead_s == 0.5 and PipelineConfig(deskew_lookahead_s=0).deskew_lookahead_s == 0
    with pytest.raises(InputError, match="deskew_lookahead_s"):
        PipelineConfig(deskew_lookahead_s=bad)


def test_no_navigation_after_the_lookahead_enters_the_motion():
    """A wild DVL sample after the scan's end changes the motion only when the lookahead reaches it."""
    t0, t1 = 10.0, 10.33
    ta, rpy, td, v, ok = navigation(t0, t1, np.array([0.3, 0.0, 0.0]), 0.0, rate_att=20.0)
    late = td > t1 + 0.05
    assert late.any()
    v_wild = v.copy()
    v_wild[late] = [3.0, 2.0, 1.0]
    for lookahead_s, same in ((0.0, True), (0.5, False)):
        a = scan_motion(ta, rpy, td, v, ok, np.eye(3), t0, t1, lookahead_s=lookahead_s)
        b = scan_motion(ta, rpy, td, v_wild, ok, np.eye(3), t0, t1, lookahead_s=lookahead_s)
        assert np.array_equal(a.p_world_vehicle_m, b.p_world_vehicle_m) is same


def test_a_pose_reexpressed_in_another_sensor_frame_keeps_its_world_pose_and_turns_its_covariance():
    from semslam.pipeline.deskew import reexpressed

    A = RigidTransform.from_xyz_rpy((0.05, -0.02, 0.01), (0.0, 0.0, np.pi / 2)).matrix  # T_new_old
    T_old = RigidTransform.from_xyz_rpy((0.3, 0.1, 1.8), (0.1, -0.2, 0.4)).matrix
    C = np.diag([1e-6, 4e-6, 9e-6, 1e-4, 2e-4, 3e-4])
    T_new, C_new = reexpressed(A, T_old, C)
    np.testing.assert_allclose(T_new, A @ T_old, atol=1e-15)
    np.testing.assert_allclose(np.diag(C_new)[:3], [4e-6, 1e-6, 9e-6], rtol=1e-9)  # x and y swap under 90 deg of yaw
    # against sampling, for a turn that mixes the angles: rpy of A @ T(rpy + noise) has the propagated covariance
    from semslam.geometry import rpy_from_rotation

    A = RigidTransform.from_xyz_rpy((0.05, -0.02, 0.01), (0.3, -0.2, 1.2)).matrix
    C_new = reexpressed(A, T_old, C)[1]
    assert np.abs(C_new[3:, 3:] - C[3:, 3:]).max() > 2e-5  # mixed
    rng = np.random.default_rng(1)
    rpy0 = rpy_from_rotation(T_old[:3, :3])
    samples = np.array([rpy_from_rotation(A[:3, :3] @ rotation_from_rpy(*(rpy0 + d)))
                        for d in rng.multivariate_normal(np.zeros(3), C[3:, 3:], 20000)])
    np.testing.assert_allclose(np.cov(samples.T), C_new[3:, 3:], rtol=0.05, atol=5e-6)


def test_sensor_motion_between_two_stamps_of_a_straight_run():
    from semslam.pipeline.deskew import sensor_motion_between

    t0, t1 = 0.0, 0.3
    motion = scan_motion(*navigation(t0, t1, np.array([0.3, 0.0, 0.0]), 0.0), np.eye(3), t0, t1)
    A = sensor_motion_between(motion, T_VS, 0.3, 0.1)  # a point seen at 0.3 s, in the frame at 0.1 s
    np.testing.assert_allclose(A[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(A[:3, 3], [0.06, 0.0, 0.0], atol=1e-9)  # the vehicle moved 6 cm forward


def test_dense_per_point_stamps_share_transforms_within_a_fraction_of_a_millimetre():
    """20k points with their own stamps (17 us apart, as a per-point-stamped lidar): transforms are shared over
    STAMP_SHARE_S, the result stays within 0.3 mm of the exact scene at the scan's end."""
    rng = np.random.default_rng(2)
    t0, t1 = 0.0, 1.0 / 3.0
    v_body, yaw_rate = np.array([1.0, 0.0, 0.0]), 1.0
    stamps = np.sort(rng.uniform(t0, t1, 20000))
    R1, p1 = vehicle_pose(t1, v_body, yaw_rate)
    world = p1 + rng.uniform([-2, -2, 3], [2, 2, 4], (20000, 3))
    raw = scan_of_static_points(world, stamps, v_body, yaw_rate)
    truth = scan_of_static_points(world, np.full(20000, t1), v_body, yaw_rate)
    out = deskew_points(raw, stamps, scan_motion(*navigation(t0, t1, v_body, yaw_rate), np.eye(3), t0, t1), T_VS, t1)
    assert np.max(np.linalg.norm(out - truth, axis=1)) < 3e-4
