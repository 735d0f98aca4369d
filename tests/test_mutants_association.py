"""Tests that kill surviving mutants of ``semslam/slam/association.py`` (benchmarks/mutation.py)."""

from __future__ import annotations

import numpy as np

from semslam.slam.association import Innovation


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
