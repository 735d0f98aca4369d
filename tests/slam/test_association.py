"""Landmark association (``semslam/slam/association.py``): the innovation's rows and its clamped unobservable
variance, the innovation's Jacobian with respect to the AHRS yaw bias (oracle: central differences of the
innovation itself), the unobservable rotation axes of a measurement with two of them, and JCBB's joint test."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.detection import Detection
from semslam.geometry import RigidTransform, rotation_from_rpy
from semslam.slam.association import Innovation, innovation, measurement_from_detection
from semslam.slam.ekf import SemanticEkf
from semslam.symmetry import Symmetry


def test_innovation_rows_pose_and_position():
    """Catches swapped row selections in ``Innovation.rows``: ``"pose"`` gives all ``m`` rows (H, nu, R), any
    other test (``"position"``) the first three position rows and the 3 x 3 position noise block."""
    rng = np.random.default_rng(0)
    H, nu = rng.normal(size=(6, 12)), rng.normal(size=6)
    R = np.diag(np.arange(1.0, 7.0))
    inn = Innovation(np.arange(12), H, nu, R, R + 1.0, 9.0, 4.0)
    Hp, nup, Rp = inn.rows("pose")
    assert Hp is H and nup is nu and Rp is R and inn.dof_pose == 6
    Hq, nuq, Rq = inn.rows("position")
    np.testing.assert_array_equal(Hq, H[:3])
    np.testing.assert_array_equal(nuq, nu[:3])
    np.testing.assert_array_equal(Rq, np.diag([1.0, 2.0, 3.0]))


def test_unobservable_axis_gets_the_clamped_positive_variance():
    """Catches a wrong clamp of the huge variance about a symmetry axis (``- U^T U var`` for ``+``): the
    rotation-noise block of a continuous-symmetry measurement must keep the observed directions' noise
    (projected, ``Pu C Pu``), give exactly ``unobservable_var_rad2`` along the axis, and stay positive definite."""
    from semslam.detection import Detection
    from semslam.geometry import RigidTransform, rotation_from_rpy
    from semslam.slam.association import measurement_from_detection
    from semslam.symmetry import Symmetry

    R_so = rotation_from_rpy(0.2, -0.1, 0.7)
    cov = np.diag([1e-4, 2e-4, 3e-4, 0.01, 0.02, 0.03])
    det = Detection("socket", 0.0, RigidTransform.from_rotation_translation(R_so, [1.0, 0.5, 2.0]), cov)
    meas = measurement_from_detection(det, RigidTransform.identity(), symmetry=Symmetry("continuous",
                                                                                       axis_object=[0.0, 0.0, 1.0]),
                                      unobservable_var_rad2=0.25)
    C = meas.noise_cov[3:6, 3:6]
    u = R_so @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(meas.unobservable_axes_vehicle, [u] if meas.unobservable_axes_vehicle[0] @ u > 0
                               else [-u], atol=1e-12)
    np.testing.assert_allclose(C @ u, 0.25 * u, atol=1e-12)
    assert np.linalg.eigvalsh(meas.noise_cov).min() > 0
    # observed directions: the unclamped rotation covariance (world-rate Jacobian E applied), projected
    from semslam.slam import _ekf_kernels as kern

    E = kern.rpy_to_world_rate(det.T_sensor_object.as_rpy())
    C0 = E @ cov[3:6, 3:6] @ E.T
    Pu = np.eye(3) - np.outer(u, u)
    np.testing.assert_allclose(Pu @ C @ Pu, Pu @ C0 @ Pu, atol=1e-12)


def _scene(yaw_bias: bool):
    n = 7 if yaw_bias else 6
    ekf = SemanticEkf(np.array([1.0, -0.5, 2.0]), np.array([0.3, 0.0, 0.0]), np.eye(n) * 1e-3, yaw_bias=yaw_bias)
    if yaw_bias:
        ekf.xa[ekf.i_yaw] = 0.04
    G = np.zeros((6, ekf.n_v))
    G[0:3, 0:3] = np.eye(3)
    ekf.add_landmark(np.array([4.0, 1.0, 3.0, 0.1, -0.2, 0.6]), G, np.eye(6) * 1e-3, label="valve", stamp_s=0.0)
    R_true = ekf.true_attitude(R_AHRS)
    R_vo = R_true.T @ rotation_from_rpy(0.1, -0.2, 0.6) @ rotation_from_rpy(0.01, -0.005, 0.008)  # ~0.01 rad off
    det = Detection("valve", 0.9, RigidTransform.from_rotation_translation(R_vo, [2.9, 1.7, 1.1]), np.eye(6) * 1e-4)
    x = measurement_from_detection(det, RigidTransform.identity(), index=0)
    return ekf, x


R_AHRS = rotation_from_rpy(0.05, 0.02, 0.3)


@pytest.mark.parametrize("mode", ["rpy", "rotvec"])
def test_yaw_bias_column_of_the_innovation_jacobian_is_the_derivative(mode):
    """Catches a wrong yaw-bias entry of the orientation rows (``H[5, b] = 2`` in the rpy innovation) and the
    rotation-vector rows' yaw-bias column left out (``if not ekf.yaw_bias``): ``H``'s yaw-bias column is minus the
    derivative of the innovation with respect to the bias (central differences, h = 1e-6): exactly for the position
    rows, to first order for the orientation rows (the filter linearises ``log`` at a small orientation
    innovation, here ~0.01 rad: 2 % tolerance, while the two bugs are off by 1)."""
    ekf, x = _scene(True)
    R_ahrs = R_AHRS
    inn = innovation(ekf, 0, x, R_ahrs, None, orientation_innovation=mode)
    assert len(inn.nu) == 6
    col = list(inn.idx).index(ekf.i_yaw)
    b, h = float(ekf.xa[ekf.i_yaw]), 1e-6
    nus = []
    for s in (1, -1):
        ekf.xa[ekf.i_yaw] = b + s * h
        nus.append(innovation(ekf, 0, x, R_ahrs, None, orientation_innovation=mode).nu)
    ekf.xa[ekf.i_yaw] = b
    fd = -(nus[0] - nus[1]) / (2 * h)
    np.testing.assert_allclose(inn.H[:3, col], fd[:3], atol=1e-7)
    np.testing.assert_allclose(inn.H[3:, col], fd[3:], atol=0.02)
    assert np.abs(inn.H[3:, col]).max() > 0.5


def test_two_unobservable_axes_are_kept_orthonormal():
    """Catches ``reshape(+1, 3)`` for ``reshape(-1, 3)`` in the axes' orthonormalisation (it fails for more than one
    axis): a detection of a continuously symmetric object (axis z) whose covariance also leaves the rotation about
    x unknown has two unobservable axes, returned as two orthonormal rows spanning z and x of the vehicle frame."""
    cov = np.diag([1e-4, 1e-4, 1e-4, 4.0, 1e-3, 1e-3])
    det = Detection("pipe", 0.9, RigidTransform.from_rotation_translation(np.eye(3), [3.0, 0.0, 0.0]), cov)
    x = measurement_from_detection(det, RigidTransform.identity(), index=0,
                                   symmetry=Symmetry("continuous", axis_object=[0.0, 0.0, 1.0]))
    U = x.unobservable_axes_vehicle
    assert U.shape == (2, 3)
    np.testing.assert_allclose(U @ U.T, np.eye(2), atol=1e-12)
    P = U.T @ U   # projector on their span: x and z
    np.testing.assert_allclose(P, np.diag([1.0, 0.0, 1.0]), atol=1e-9)


@pytest.mark.parametrize("sigmas", [2.0, 3.2])
def test_jcbb_rejects_a_jointly_incompatible_pair_of_individually_gated_pairings(sigmas):
    """Catches a joint innovation covariance without the measurement noise (``H P H^T - R``): two precisely mapped
    landmarks far apart, each detected ``sigmas`` detection-sigmas off along x. At 3.2 sigma each pairing passes its
    own 3-dof gate (NEES 10.2 < 11.3) but the joint NEES 20.5 exceeds the 6-dof gate (16.8): JCBB keeps one pairing.
    At 2 sigma (joint 8) it keeps both."""
    from semslam.slam.association import GateThresholds, associate_jcbb

    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-10)
    G = np.zeros((6, 6))
    G[0:3, 0:3] = np.eye(3)
    for p in ([4.0, 0.0, 0.0], [0.0, 5.0, 0.0]):
        ekf.add_landmark(np.r_[p, 0.0, 0.0, 0.0], G, np.eye(6) * 1e-10, label="valve", stamp_s=0.0)
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3])
    meas = [measurement_from_detection(Detection("valve", 0.9, RigidTransform.from_rotation_translation(
        np.eye(3), np.array(p) + [sigmas * 0.01, 0.0, 0.0]), cov), RigidTransform.identity(), index=a)
        for a, p in enumerate(([4.0, 0.0, 0.0], [0.0, 5.0, 0.0]))]
    inns = {(a, b): innovation(ekf, b, x, np.eye(3), None) for a, x in enumerate(meas) for b in range(2)}
    d2 = np.array([[inns[(a, b)].d2_position for b in range(2)] for a in range(2)])
    thr = GateThresholds(0.99)
    gate = d2 <= thr.threshold(3)
    assert gate[0, 0] and gate[1, 1] and not gate[0, 1] and not gate[1, 0]
    pairs = associate_jcbb(inns, ekf, 2, gate, 0.99)
    if sigmas > 3:
        assert d2[0, 0] + d2[1, 1] > thr.threshold(6)
        assert len(pairs) == 1 and pairs[0] in [(0, 0), (1, 1)]
    else:
        assert sorted(pairs) == [(0, 0), (1, 1)]
