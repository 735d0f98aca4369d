"""REP-103 (ENU/FLU) <-> semslam (NED/FRD) conversions: hand cases, round trips, scipy as the oracle."""

from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.errors import InputError
from semslam.geometry import rotation_from_rpy
from semslam.io.ros import frames as F


def _quat_enu(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """ROS quat_xyzw of FLU body in ENU world from ROS roll/pitch/yaw (intrinsic Z-Y-X)."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat()  # scipy: scalar last, like ROS


@pytest.mark.parametrize(
    ("heading", "yaw_enu", "yaw_ned"),
    [("east", 0.0, np.pi / 2), ("north", np.pi / 2, 0.0), ("west", np.pi, -np.pi / 2),
     ("north-east", np.pi / 4, np.pi / 4), ("south-east", -np.pi / 4, 3 * np.pi / 4)],
)
def test_heading_hand_cases(heading: str, yaw_enu: float, yaw_ned: float) -> None:
    rpy = F.rpy_ned_frd_from_quat_xyzw(_quat_enu(0.0, 0.0, yaw_enu))
    np.testing.assert_allclose(rpy, [0.0, 0.0, yaw_ned], atol=1e-12)
    # the vehicle's nose (FRD x) points where the heading says, in NED
    nose_ned = F.R_world_ned_vehicle_frd_from_quat_xyzw(_quat_enu(0.0, 0.0, yaw_enu)) @ [1.0, 0.0, 0.0]
    np.testing.assert_allclose(nose_ned, [np.cos(yaw_ned), np.sin(yaw_ned), 0.0], atol=1e-12)


def test_facing_south_is_yaw_pi() -> None:
    yaw = F.rpy_ned_frd_from_quat_xyzw(_quat_enu(0.0, 0.0, -np.pi / 2))[2]
    assert abs(abs(yaw) - np.pi) < 1e-12


def test_roll_right_is_positive_and_pitch_up_is_positive() -> None:
    a = 0.3
    # starboard down: in FLU a positive roll about x (forward) lifts the left (+y) side
    R = F.R_world_ned_vehicle_frd_from_quat_xyzw(_quat_enu(a, 0.0, 0.0))
    assert (R @ [0.0, 1.0, 0.0])[2] > 0.2  # starboard (FRD +y) points down (NED +z)
    np.testing.assert_allclose(F.rpy_ned_frd_from_quat_xyzw(_quat_enu(a, 0.0, 0.0)), [a, 0.0, np.pi / 2], atol=1e-12)
    # nose up: negative ROS pitch (about the left axis), positive FRD pitch
    R = F.R_world_ned_vehicle_frd_from_quat_xyzw(_quat_enu(0.0, -a, np.pi / 2))
    assert (R @ [1.0, 0.0, 0.0])[2] < -0.2  # nose points up (NED -z)
    np.testing.assert_allclose(F.rpy_ned_frd_from_quat_xyzw(_quat_enu(0.0, -a, np.pi / 2)), [0.0, a, 0.0], atol=1e-12)


def test_euler_relation_random() -> None:
    """roll_ned = roll_enu, pitch_ned = -pitch_enu, yaw_ned = pi/2 - yaw_enu (wrapped)."""
    rng = np.random.default_rng(103)
    for _ in range(200):
        roll, pitch, yaw = rng.uniform(-3.0, 3.0), rng.uniform(-1.5, 1.5), rng.uniform(-np.pi, np.pi)
        rpy = F.rpy_ned_frd_from_quat_xyzw(_quat_enu(roll, pitch, yaw))
        expected_yaw = (np.pi / 2 - yaw + np.pi) % (2 * np.pi) - np.pi
        np.testing.assert_allclose(rpy[:2], [roll, -pitch], atol=1e-9)
        assert abs((rpy[2] - expected_yaw + np.pi) % (2 * np.pi) - np.pi) < 1e-9
        np.testing.assert_allclose(rotation_from_rpy(*rpy), F.R_world_ned_vehicle_frd_from_quat_xyzw(
            _quat_enu(roll, pitch, yaw)), atol=1e-12)


def test_quaternion_maths_against_scipy() -> None:
    rng = np.random.default_rng(7)
    for _ in range(200):
        q = rng.normal(size=4) * rng.uniform(0.1, 10.0)  # not normalised on purpose
        R_enu_flu = Rotation.from_quat(q).as_matrix()
        expected = F.C_NED_ENU @ R_enu_flu @ F.C_FRD_FLU
        np.testing.assert_allclose(F.R_world_ned_vehicle_frd_from_quat_xyzw(q), expected, atol=1e-12)
        # and the inverse: quat back in ROS order, w >= 0
        q_back = F.quat_xyzw_from_R_world_ned_vehicle_frd(expected)
        q_unit = q / np.linalg.norm(q) * np.sign(q[3])
        np.testing.assert_allclose(q_back, q_unit, atol=1e-9)
        assert q_back[3] >= 0
        np.testing.assert_allclose(Rotation.from_quat(q_back).as_matrix(), R_enu_flu, atol=1e-12)


def test_frame_matrices_are_proper_rotations() -> None:
    for C in (F.C_NED_ENU, F.C_FRD_FLU):
        np.testing.assert_allclose(C @ C, np.eye(3))
        assert np.linalg.det(C) == pytest.approx(1.0)


def test_vectors_hand_cases_and_round_trips() -> None:
    np.testing.assert_array_equal(F.vectors_ned_from_enu([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    np.testing.assert_array_equal(F.vectors_frd_from_flu([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0])
    np.testing.assert_array_equal(F.rates_frd_from_flu([0.1, 0.2, 0.3]), [0.1, -0.2, -0.3])
    v = np.random.default_rng(1).normal(size=(50, 3))
    np.testing.assert_allclose(F.vectors_enu_from_ned(F.vectors_ned_from_enu(v)), v)
    np.testing.assert_allclose(F.vectors_flu_from_frd(F.vectors_frd_from_flu(v)), v)
    np.testing.assert_allclose(F.rates_flu_from_frd(F.rates_frd_from_flu(v)), v)
    assert F.vectors_ned_from_enu(v).shape == (50, 3)
    with pytest.raises(InputError, match="'v_enu' argument of vectors_ned_from_enu must have shape"):
        F.vectors_ned_from_enu(np.zeros((4, 2)))


def test_rotations_round_trip_and_body_vectors_consistent() -> None:
    rng = np.random.default_rng(2)
    for R_enu_flu in Rotation.random(50, random_state=3).as_matrix():
        R_ned_frd = F.R_world_ned_vehicle_frd_from_R_world_enu_vehicle_flu(R_enu_flu)
        np.testing.assert_allclose(F.R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd(R_ned_frd), R_enu_flu,
                                   atol=1e-12)
        # a world vector seen from the body is the same physical vector in both conventions
        v_enu = rng.normal(size=3)
        v_flu = R_enu_flu.T @ v_enu
        np.testing.assert_allclose(R_ned_frd.T @ F.vectors_ned_from_enu(v_enu), F.vectors_frd_from_flu(v_flu),
                                   atol=1e-12)
    with pytest.raises(InputError, match="'R_world_enu_vehicle_flu' argument"):
        F.R_world_ned_vehicle_frd_from_R_world_enu_vehicle_flu(np.diag([1.0, 1.0, -1.0]))


def test_body_rates_integrate_consistently() -> None:
    """R(t) = R0 expm([w_flu] t) in ROS is R0' expm([w_frd] t) in semslam with w_frd = rates_frd_from_flu(w_flu)."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        R0 = Rotation.random(random_state=int(rng.integers(1000))).as_matrix()
        w_flu, dt = rng.normal(size=3), 0.37
        R1_enu = R0 @ Rotation.from_rotvec(w_flu * dt).as_matrix()
        R0_ned = F.R_world_ned_vehicle_frd_from_R_world_enu_vehicle_flu(R0)
        R1_ned = F.R_world_ned_vehicle_frd_from_R_world_enu_vehicle_flu(R1_enu)
        w_frd = F.rates_frd_from_flu(w_flu)
        np.testing.assert_allclose(R0_ned @ Rotation.from_rotvec(w_frd * dt).as_matrix(), R1_ned, atol=1e-12)


def test_imu_message_to_ned_frd() -> None:
    yaw_enu = 0.4
    q = _quat_enu(0.05, -0.02, yaw_enu)
    msg = NS(orientation=NS(x=q[0], y=q[1], z=q[2], w=q[3]), orientation_covariance=np.zeros(9),
             angular_velocity=NS(x=0.01, y=0.02, z=0.5), linear_acceleration=NS(x=0.1, y=-0.2, z=9.81))
    rpy, omega_frd, acc_frd = F.imu_to_ned_frd(msg)
    np.testing.assert_allclose(rpy, [0.05, 0.02, np.pi / 2 - yaw_enu], atol=1e-12)
    np.testing.assert_allclose(omega_frd, [0.01, -0.02, -0.5])  # turning left = negative yaw rate in FRD
    np.testing.assert_allclose(acc_frd, [0.1, 0.2, -9.81])  # at rest a FRD accelerometer reads -g on z
    msg.orientation_covariance = np.array([-1.0] + [0.0] * 8)  # REP-145: no orientation
    assert np.isnan(F.imu_to_ned_frd(msg)[0]).all()


@pytest.mark.parametrize("bad", [[0, 0, 0, 0], [np.nan, 0, 0, 1], [0, 0, 1], "abcd"])
def test_bad_quaternions_raise_input_error(bad) -> None:
    with pytest.raises(InputError, match="'quat_xyzw' argument of R_world_ned_vehicle_frd_from_quat_xyzw must be"):
        F.R_world_ned_vehicle_frd_from_quat_xyzw(bad)
