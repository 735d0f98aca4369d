"""The RTS smoother against an independent batch solution (issue 20, item 5).

A small linear-Gaussian run is driven through the public :class:`SemanticEkf` + :class:`RtsRecorder` API
(attitude fixed within each step, so the EKF is the exact Kalman filter), and the same problem is solved as one
dense weighted least-squares: unknowns ``x_0 .. x_K`` (and the landmark), equations for the prior, every
process step (``x_k - F_k x_{k-1} ~ N(0, Q_k)``, ``F`` and ``Q`` written here from the model), the landmark
initialisation and every measurement. The smoothed means are the solution of the normal equations, the
smoothed covariances the blocks of the inverse information matrix.
"""

from __future__ import annotations

import numpy as np
import pytest

from semslam.geometry import rotation_from_rpy
from semslam.slam.ekf import SemanticEkf
from semslam.slam.smoother import RtsRecorder

Q_BODY = np.array([0.05, 0.02, 0.03])  # velocity_rw per body axis (m/s^1.5)


class _Batch:
    """Dense weighted least squares ``sum_i |A_i y - r_i|^2_{W_i^-1}`` over the stacked unknown ``y``."""

    def __init__(self, n):
        self.L = np.zeros((n, n))
        self.b = np.zeros(n)

    def add(self, cols, A, r, C):
        W = np.linalg.inv(C)
        self.L[np.ix_(cols, cols)] += A.T @ W @ A
        self.b[cols] += A.T @ W @ r

    def solve(self):
        cov = np.linalg.inv(self.L)
        return cov @ self.b, cov


def _process(dt, R):
    """Constant-velocity model in the world frame with body-frame velocity: ``F``, ``Q`` (6 x 6)."""
    F = np.eye(6)
    F[0:3, 3:6] = R * dt
    Qb = np.diag(Q_BODY**2)
    Q = np.zeros((6, 6))
    Q[0:3, 0:3] = R @ Qb @ R.T * dt**3 / 3
    Q[0:3, 3:6] = R @ Qb * dt**2 / 2
    Q[3:6, 0:3] = Q[0:3, 3:6].T
    Q[3:6, 3:6] = Qb * dt
    return F, Q


def _run(seed, n_steps=30, landmark_at=None, compress=False):
    """Drive the filter and the batch with the same script; return (smoothed, filtered, batch mean, batch cov)."""
    rng = np.random.default_rng(seed)
    m0 = np.r_[1.0, -2.0, 0.5, 0.4, 0.0, 0.05]
    A = rng.normal(size=(6, 6)) * 0.05
    P0 = A @ A.T + np.diag([0.04, 0.04, 0.01, 0.01, 0.01, 0.01])
    ekf = SemanticEkf(m0[:3], m0[3:], P0)
    rec = RtsRecorder(n_keep=6)
    ekf.recorder = rec
    n_lm = 6 if landmark_at is not None else 0
    nvar = 6 * (n_steps + 1) + n_lm
    batch = _Batch(nvar)
    X = lambda k: np.arange(6 * k, 6 * k + 6)  # noqa: E731
    LM = np.arange(6 * (n_steps + 1), nvar)
    batch.add(X(0), np.eye(6), m0, P0)
    truth = m0 + np.linalg.cholesky(P0) @ rng.normal(size=6)
    l_true = truth[:3] + [3.0, 1.0, 0.5]
    filtered = [(ekf.xa[:6].copy(), ekf.Paa[:6, :6].copy())]
    rec.mark(ekf)
    for k in range(1, n_steps + 1):
        dt = float(rng.uniform(0.2, 0.6))
        R = rotation_from_rpy(0.05 * np.sin(k), -0.03, 0.2 * k)
        F, Q = _process(dt, R)
        truth = F @ truth + np.linalg.cholesky(Q) @ rng.normal(size=6)
        ekf.predict(dt, R, velocity_rw=tuple(Q_BODY))
        batch.add(np.r_[X(k - 1), X(k)], np.hstack([-F, np.eye(6)]), np.zeros(6), Q)
        if k == landmark_at:  # landmark = vehicle position + a measured offset (noise N on that offset)
            z = l_true - truth[:3] + rng.normal(0.0, 0.05, 3)
            G = np.zeros((6, 6))
            G[0:3, 0:3] = np.eye(3)
            N = np.diag([0.05**2] * 3 + [1.0] * 3)
            ekf.add_landmark(np.r_[ekf.mean(np.arange(3)) + z, 0.0, 0.0, 0.0], G, N, label="valve", stamp_s=0.0)
            # l - G x_k = [z; 0] + n
            batch.add(np.r_[X(k), LM], np.hstack([-G, np.eye(6)]), np.r_[z, 0.0, 0.0, 0.0], N)
            if compress:  # the landmark goes passive (compressed filter) until it is observed again
                ekf.set_active_landmarks([])
        if compress and landmark_at is not None and k == landmark_at + 11:
            ekf.set_active_landmarks([0])
        if k % 2 == 0:  # DVL-like velocity
            Rn = np.diag([0.01**2, 0.015**2, 0.02**2])
            z = truth[3:6] + np.sqrt(np.diag(Rn)) * rng.normal(size=3)
            ekf.update(np.arange(3, 6), np.eye(3), z - ekf.mean(np.arange(3, 6)), Rn)
            batch.add(X(k)[3:6], np.eye(3), z, Rn)
        if k % 9 == 0:  # sparse absolute position fix
            Rn = np.diag([0.1**2, 0.1**2, 0.05**2])
            z = truth[0:3] + np.sqrt(np.diag(Rn)) * rng.normal(size=3)
            ekf.update(np.arange(3), np.eye(3), z - ekf.mean(np.arange(3)), Rn)
            batch.add(X(k)[0:3], np.eye(3), z, Rn)
        if landmark_at is not None and k > landmark_at + 10 and k % 3 == 0:  # relative: R^T (l - p)
            off = ekf.landmarks[0].offset
            idx = np.r_[0:3, off:off + 3]
            H = np.hstack([-R.T, R.T])
            Rn = np.eye(3) * 0.02**2
            z = R.T @ (l_true - truth[:3]) + rng.normal(0.0, 0.02, 3)
            ekf.update(idx, H, z - H @ ekf.mean(idx), Rn)
            batch.add(np.r_[X(k)[0:3], LM[0:3]], H, z, Rn)
        rec.mark(ekf)
        filtered.append((ekf.xa[:6].copy(), ekf.Paa[:6, :6].copy()))
    smoothed = rec.smooth(ekf)
    y, C = batch.solve()
    return smoothed, filtered, y, C, ekf


@pytest.mark.parametrize("landmark_at,compress", [(None, False), (6, False), (6, True)])
def test_smoother_equals_batch_least_squares(landmark_at, compress):
    """Catches any error in the backward pass: a gain with ``P^-`` not inverted or built from the wrong node
    (``P_j`` for ``P_{j-1}``), a missing ``F^T``, the covariance correction with the wrong sign or without
    ``C^T``, marks shifted by one node, a transition not composed (the landmark augmentation, or two
    predictions between marks), or the filtered state returned: smoothed means and covariances at every epoch
    agree with the dense batch solution to 1e-6. ``compress``: the landmark is passive (compressed update)
    between its initialisation and its re-observation."""
    smoothed, filtered, y, C, ekf = _run(1, landmark_at=landmark_at, compress=compress)
    K = len(filtered)
    assert smoothed is not None and smoothed.x.shape == (K, 6) and smoothed.P.shape == (K, 6, 6)
    for k in range(K):
        s = slice(6 * k, 6 * k + 6)
        np.testing.assert_allclose(smoothed.x[k], y[s], rtol=0, atol=1e-6, err_msg=f"mean at epoch {k}")
        np.testing.assert_allclose(smoothed.P[k], C[s, s], rtol=1e-6, atol=1e-9, err_msg=f"cov at epoch {k}")
    # and the batch's last epoch is the filter's (the oracle is consistent with the filter itself)
    np.testing.assert_allclose(y[6 * (K - 1):6 * K], filtered[-1][0], atol=1e-6)
    np.testing.assert_allclose(C[6 * (K - 1):6 * K, 6 * (K - 1):6 * K], filtered[-1][1], rtol=1e-6, atol=1e-9)
    if landmark_at is not None:  # the final landmark estimate is the batch's too
        np.testing.assert_allclose(ekf.landmark_pose(0)[:3], y[-6:-3], atol=1e-6)
        np.testing.assert_allclose(ekf.landmark_cov(0)[:3, :3], C[-6:-3, -6:-3], rtol=1e-6, atol=1e-9)


def test_smoothing_is_not_trivial_here():
    """Guards the oracle test above against passing vacuously (catches a smoother that returns the filtered
    states): in this run the smoothed estimate differs from the filtered one at early epochs by more than
    the tolerance, and its covariance is never larger."""
    smoothed, filtered, y, C, _ = _run(1, landmark_at=6)
    diff = max(np.abs(smoothed.x[k] - filtered[k][0]).max() for k in range(len(filtered) - 1))
    assert diff > 1e-3
    shrink = [np.trace(filtered[k][1]) - np.trace(smoothed.P[k]) for k in range(len(filtered))]
    assert min(shrink) > -1e-12 and max(shrink) > 1e-3
    for k in range(len(filtered)):
        assert np.linalg.eigvalsh(filtered[k][1] - smoothed.P[k]).min() > -1e-10


def test_smoother_with_an_unmarked_epoch_and_repeated_updates():
    """Catches a recorder that opens a node per update (instead of per transition) or that does not compose
    consecutive transitions (two predictions with no update or mark between them): two updates in a row and an
    unmarked, unobserved epoch give the same smoothed states as the batch."""
    rng = np.random.default_rng(3)
    P0 = np.diag([0.1, 0.1, 0.1, 0.02, 0.02, 0.02])
    m0 = np.r_[0.0, 0.0, 0.0, 0.5, 0.1, 0.0]
    ekf = SemanticEkf(m0[:3], m0[3:], P0)
    rec = RtsRecorder()
    ekf.recorder = rec
    batch = _Batch(6 * 4)
    X = lambda k: np.arange(6 * k, 6 * k + 6)  # noqa: E731
    batch.add(X(0), np.eye(6), m0, P0)
    rec.mark(ekf)  # epoch 0 = variable 0
    marked = [0]
    for k in range(1, 4):
        dt, R = 0.5, rotation_from_rpy(0.0, 0.0, 0.4 * k)
        F, Q = _process(dt, R)
        ekf.predict(dt, R, velocity_rw=tuple(Q_BODY))
        batch.add(np.r_[X(k - 1), X(k)], np.hstack([-F, np.eye(6)]), np.zeros(6), Q)
        for _ in range(0 if k == 2 else 2):
            z = rng.normal(0.0, 0.1, 3)
            ekf.update(np.arange(3), np.eye(3), z - ekf.mean(np.arange(3)), np.eye(3) * 0.01)
            batch.add(X(k)[0:3], np.eye(3), z, np.eye(3) * 0.01)
        if k != 2:  # epoch 2: no update, no mark: its prediction must be composed with epoch 3's
            rec.mark(ekf)
            marked.append(k)
    sm = rec.smooth(ekf)
    y, C = batch.solve()
    assert len(sm.x) == len(marked)
    for i, k in enumerate(marked):
        s = slice(6 * k, 6 * k + 6)
        np.testing.assert_allclose(sm.x[i], y[s], atol=1e-6)
        np.testing.assert_allclose(sm.P[i], C[s, s], rtol=1e-6, atol=1e-9)
