"""The graph's factors against the filter's models (issue 17): the landmark factor is the EKF's measurement model
(:func:`innovation`), its Jacobians are derivatives of its error, and the segment pre-integration is the exact
marginal of the eliminated states."""

from __future__ import annotations

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam", reason="the graph backends need GTSAM (pip install gtsam)")

from semslam.detection import Detection  # noqa: E402
from semslam.errors import SlamError  # noqa: E402
from semslam.geometry import RigidTransform, rotation_from_rpy  # noqa: E402
from semslam.slam.association import innovation, measurement_from_detection  # noqa: E402
from semslam.slam.graph import factors as fac  # noqa: E402
from semslam.slam.graph.segment import SegmentAccumulator  # noqa: E402
from semslam.symmetry import Symmetry  # noqa: E402


def _case(rng, symmetry, yaw_bias):
    cov = np.diag([1e-4, 1e-4, 2e-4, 4e-4, 4e-4, 9e-4])
    det = Detection(label="a", score=0.0, T_sensor_object=RigidTransform.from_xyz_rpy([1.0, 0.2, 1.5], [0.1, -0.2, 0.7]),
                    covariance_6x6=cov, stamp_s=1.0)
    meas = measurement_from_detection(det, RigidTransform.from_xyz_rpy([0.5, 0, 0.2], [0, 0.3, 0]), symmetry=symmetry)
    n_v = 7 if yaw_bias else 6
    x = np.r_[rng.normal(0, 1, 3), 0.3, 0.0, 0.0, [0.02] if yaw_bias else []]
    lm = np.r_[x[:3] + rng.normal(0, 1, 3), rng.normal(0, 0.3, 3)]
    return meas, n_v, x, lm


class _Ekf:
    def __init__(self, x, lm, n_v, yaw_bias):
        self.n_v, self.yaw_bias, self.i_yaw = n_v, yaw_bias, n_v - 1 if yaw_bias else -1
        self.landmarks = [type("I", (), {"offset": n_v})()]
        self.x = np.r_[x, lm]

    def mean(self, idx):
        return self.x[idx]

    def true_attitude(self, R):
        from semslam.slam import _ekf_kernels as kern

        return kern.rot_z(-float(self.x[self.i_yaw])) @ R if self.yaw_bias else R

    def innovation_cov(self, idx, H, N):
        return N


@pytest.mark.parametrize("symmetry", [Symmetry(), Symmetry("discrete", np.array([0.0, 1.0, 0.0]), 2),
                                      Symmetry("continuous", np.array([0.0, 0.0, 1.0]), 0)])
@pytest.mark.parametrize("yaw_bias", [False, True])
def test_landmark_factor_is_the_filter_model_and_its_jacobians_are_derivatives(symmetry, yaw_bias):
    rng = np.random.default_rng(4)
    meas, n_v, x, lm = _case(rng, symmetry, yaw_bias)
    R_ahrs = rotation_from_rpy(0.05, -0.03, 1.2)
    inn = innovation(_Ekf(x, lm, n_v, yaw_bias), 0, meas, R_ahrs, None)
    f = fac.landmark_factor(fac.X(0), fac.L(0), meas, R_ahrs, "pose", inn.R, n_v=n_v, yaw_bias=yaw_bias,
                            i_yaw=n_v - 1 if yaw_bias else -1, yaw_bias_lin=float(x[-1]) if yaw_bias else 0.0)
    v = gtsam.Values()
    v.insert(fac.X(0), x)
    v.insert(fac.L(0), lm)
    e = f.unwhitenedError(v)
    assert np.allclose(e, -inn.nu, atol=1e-12)  # the filter's innovation, negated
    assert len(e) == (5 if symmetry.kind == "continuous" else 6)  # the free rotation removed, not a huge sigma
    # whitened Jacobian against central differences of the whitened error
    A, b = f.linearize(v).jacobian()
    y = np.r_[x, lm]
    num, num_u = np.zeros_like(A), np.zeros_like(A)
    for c in range(len(y)):
        for s in (1, -1):
            yy = y.copy()
            yy[c] += s * 1e-6
            w = gtsam.Values()
            w.insert(fac.X(0), yy[:n_v])
            w.insert(fac.L(0), yy[n_v:])
            num[:, c] += s * f.whitenedError(w) / 2e-6
            num_u[:, c] += s * f.unwhitenedError(w) / 2e-6
    assert np.allclose(A, num, atol=1e-4 * np.abs(A).max())
    # the position rows' derivative is the filter's H (its orientation rows take Jr^-1 = I: exact at zero residual)
    assert np.allclose(num_u[0:3], inn.H[0:3], atol=1e-6)


def test_segment_rows_are_the_marginal_of_the_eliminated_states():
    """Two predictions and a measurement between keyframes: the accumulated rows give the same information on
    (X_k, X_k+1) as a dense Schur complement of the three-state problem."""
    rng = np.random.default_rng(1)
    n = 3
    F1, F2 = np.eye(n) + rng.normal(0, 0.1, (n, n)), np.eye(n) + rng.normal(0, 0.1, (n, n))
    Q1, Q2 = (np.diag(rng.uniform(0.01, 0.1, n)) for _ in range(2))
    u1, u2 = rng.normal(size=n), rng.normal(size=n)
    H, z, Rn = rng.normal(size=(2, n)), rng.normal(size=2), np.diag([0.05, 0.02])
    seg = SegmentAccumulator(n)
    seg.predict(F1, u1, Q1)
    seg.measure(H, z, Rn)
    seg.predict(F2, u2, Q2)
    A0, A1, b, unary = seg.close()
    assert not unary
    # dense: unknowns [X0, Xm, X1]; factors Xm - F1 X0 - u1, H Xm - z, X1 - F2 Xm - u2
    rows, rhs = [], []
    for (A, r, C) in (([-F1, np.eye(n), np.zeros((n, n))], u1, Q1), ([np.zeros((2, n)), H, np.zeros((2, n))], z, Rn),
                      ([np.zeros((n, n)), -F2, np.eye(n)], u2, Q2)):
        W = np.linalg.inv(np.linalg.cholesky(C))
        rows.append(W @ np.hstack(A))
        rhs.append(W @ r)
    J, r = np.vstack(rows), np.concatenate(rhs)
    L, eta = J.T @ J, J.T @ r
    keep, drop = np.r_[0:n, 2 * n:3 * n], np.r_[n:2 * n]
    S = L[np.ix_(keep, keep)] - L[np.ix_(keep, drop)] @ np.linalg.solve(L[np.ix_(drop, drop)], L[np.ix_(drop, keep)])
    s = eta[keep] - L[np.ix_(keep, drop)] @ np.linalg.solve(L[np.ix_(drop, drop)], eta[drop])
    M = np.hstack([A0, A1])
    assert np.allclose(M.T @ M, S, atol=1e-9) and np.allclose(M.T @ b, s, atol=1e-9)


def test_noise_models_refuse_non_psd_covariances_with_the_name():
    with pytest.raises(SlamError, match="covariance of detection 3 .*positive semi-definite.*-1"):
        fac.gaussian(np.diag([1.0, -1.0]), "detection 3 (elbow)")
    with pytest.raises(SlamError, match="finite square matrix"):
        fac.gaussian(np.full((2, 2), np.nan), "the initial vehicle state")
