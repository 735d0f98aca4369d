"""Oracle tests of the EKF update and prediction against the textbook dense forms (issue 20, items 1 and 4).

The oracle is written here from the equations (Kalman gain through an explicit inverse, Joseph form, dense
``F P F^T + Q``), on the full ``(x, P)`` read back through :meth:`SemanticEkf.full_state`.
"""

from __future__ import annotations

import numpy as np
import pytest

from semslam.geometry import rotation_from_rpy
from semslam.slam import _ekf_kernels as kern
from semslam.slam.ekf import SemanticEkf


def _random_filter(seed, n_landmarks=3, yaw_bias=False):
    """A filter with a random, fully correlated covariance (vehicle-landmark and landmark-landmark terms)."""
    rng = np.random.default_rng(seed)
    nv = 6 + yaw_bias
    A = rng.normal(size=(nv, nv)) * 0.3
    ekf = SemanticEkf(rng.normal(size=3), rng.normal(size=3) * 0.3, A @ A.T + 0.01 * np.eye(nv), yaw_bias=yaw_bias)
    for _ in range(n_landmarks):
        G = rng.normal(size=(6, nv)) * 0.3
        G[0:3, 0:3] += np.eye(3)
        B = rng.normal(size=(6, 6)) * 0.2
        ekf.add_landmark(np.r_[rng.uniform(-5, 5, 3), rng.uniform(-0.4, 0.4, 3)], G, B @ B.T + 1e-3 * np.eye(6),
                         label="valve", stamp_s=0.0)
    return ekf, rng


def _random_measurement(ekf, rng):
    n = ekf.n
    k = int(rng.integers(1, min(n, 12) + 1))
    idx = np.sort(rng.choice(n, k, replace=False))
    m = int(rng.integers(1, 7))
    Hc = rng.normal(size=(m, k))
    C = rng.normal(size=(m, m)) * 0.1
    Rn = C @ C.T + 1e-3 * np.eye(m)
    nu = rng.normal(size=m) * 0.05
    return idx, Hc, nu, Rn


def _dense_update(x, P, idx, Hc, nu, Rn):
    """Textbook Kalman update: ``K = P H^T S^-1``, ``x + K nu``, Joseph ``(I-KH) P (I-KH)^T + K R K^T``."""
    H = np.zeros((len(nu), len(x)))
    H[:, idx] = Hc
    S = H @ P @ H.T + Rn
    K = P @ H.T @ np.linalg.inv(S)
    IKH = np.eye(len(x)) - K @ H
    return x + K @ nu, IKH @ P @ IKH.T + K @ Rn @ K.T, K, S


def _angles_safe(ekf, x):
    """The oracle ignores the filter's angle re-parametrisation: keep the landmark angles inside +-90 deg."""
    return all(np.abs(x[lm.offset + 3:lm.offset + 6]).max() < np.pi / 2 for lm in ekf.landmarks)


@pytest.mark.parametrize("yaw_bias", [False, True])
def test_update_equals_textbook_dense_form(yaw_bias):
    """Catches any error in the gain or the covariance update: a missing transpose, ``S`` without ``R``, the
    simple form ``P - K H P`` with a non-symmetric result, an update applied on the wrong columns (``loc`` vs
    global indices), and the K = 0 "update that does nothing" (first assertion: the state did not move)."""
    ekf, rng = _random_filter(10 + yaw_bias, yaw_bias=yaw_bias)
    checked = 0
    for _ in range(40):
        x0, P0 = ekf.full_state()
        idx, Hc, nu, Rn = _random_measurement(ekf, rng)
        x1, P1, K, S = _dense_update(x0, P0, idx, Hc, nu, Rn)
        if not _angles_safe(ekf, x1):
            continue
        ekf.update(idx, Hc, nu, Rn)
        x, P = ekf.full_state()
        np.testing.assert_allclose(x, x1, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(P, P1, rtol=1e-10, atol=1e-10)
        # Joseph with the optimal gain = P - K S K^T
        np.testing.assert_allclose(P, P0 - K @ S @ K.T, rtol=1e-9, atol=1e-10)
        checked += 1
    assert checked >= 30


def test_update_of_a_compressed_filter_equals_textbook_dense_form():
    """Catches a wrong compressed (passive landmark) update: the accumulators ``phi, psi, theta`` must give the
    same full ``(x, P)`` as the dense Kalman update, for updates on the vehicle and the active landmark, while
    the passive landmarks move through their cross-covariance."""
    ekf, rng = _random_filter(3, n_landmarks=4)
    x, P = ekf.full_state()
    ekf.set_active_landmarks([2])
    off = ekf.landmarks[2].offset
    for step in range(15):
        idx = np.r_[np.arange(6), off + np.arange(6)][np.sort(rng.choice(12, int(rng.integers(2, 12)), replace=False))]
        m = int(rng.integers(1, 6))
        Hc = rng.normal(size=(m, len(idx)))
        C = rng.normal(size=(m, m)) * 0.1
        Rn = C @ C.T + 1e-3 * np.eye(m)
        nu = rng.normal(size=m) * 0.05
        x, P, _, _ = _dense_update(x, P, idx, Hc, nu, Rn)
        assert _angles_safe(ekf, x)
        ekf.update(idx, Hc, nu, Rn)
        assert ekf.compressed
        # exact views of a passive landmark before any flush
        np.testing.assert_allclose(ekf.landmark_pose(0), x[ekf.landmarks[0].offset + np.arange(6)], atol=1e-10)
        np.testing.assert_allclose(ekf.landmark_cov(1), P[np.ix_(ekf.landmarks[1].offset + np.arange(6),
                                                                  ekf.landmarks[1].offset + np.arange(6))],
                                   atol=1e-10)
    xf, Pf = ekf.full_state()
    np.testing.assert_allclose(xf, x, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Pf, P, rtol=1e-9, atol=1e-10)


def _check_moved(x_before, x_after, K, nu):
    """(a) the state moved by exactly ``K nu``."""
    np.testing.assert_allclose(x_after - x_before, K @ nu, rtol=1e-9, atol=1e-12, err_msg="state did not move by K nu")


def _check_trace(P_before, P_after, K, S):
    """(b) the trace dropped by exactly ``trace(K S K^T)`` (> 0)."""
    drop = np.trace(P_before) - np.trace(P_after)
    assert drop == pytest.approx(np.trace(K @ S @ K.T), rel=1e-9), "trace reduction != trace(K S K^T)"


def _check_rank(P_before, P_after, m):
    """(c) the information gained ``P - P+`` is positive semi-definite of rank m (the measurement's size)."""
    w = np.linalg.eigvalsh(P_before - P_after)
    assert w.min() > -1e-12 and (w > 1e-9 * max(w.max(), 1e-300)).sum() == m, "covariance did not shrink by rank m"


def _information_checks(P_before, P_after, x_before, x_after, K, S, nu):
    """Assertions that a real update satisfies and a no-op update (K = 0) violates."""
    _check_moved(x_before, x_after, K, nu)
    _check_trace(P_before, P_after, K, S)
    _check_rank(P_before, P_after, len(nu))


def test_information_gain_of_an_update():
    """Catches an update that does not shrink the covariance by the information it brings: the trace drops by
    ``trace(K S K^T)`` (the oracle's K), the drop ``P - P+`` is PSD of rank m, and the mean moves by ``K nu``."""
    ekf, rng = _random_filter(21)
    for _ in range(10):
        x0, P0 = ekf.full_state()
        idx, Hc, nu, Rn = _random_measurement(ekf, rng)
        x1, _, K, S = _dense_update(x0, P0, idx, Hc, nu, Rn)
        if not _angles_safe(ekf, x1):
            continue
        ekf.update(idx, Hc, nu, Rn)
        x, P = ekf.full_state()
        _information_checks(P0, P, x0, x, K, S, nu)


def test_the_oracle_detects_an_update_that_does_nothing(monkeypatch):
    """Negative control: with the Joseph kernel replaced by a no-op returning ``K = 0`` (the broken update),
    each of the three information checks fails on its own: (a) ``x+ - x == K nu``, (b) the trace drop equals
    ``trace(K S K^T)``, (c) ``P - P+`` has rank m; and the dense comparison of
    :func:`test_update_equals_textbook_dense_form` fails too."""

    def broken(P, x, loc, Hc, nu, Rn):
        m = len(nu)
        return np.zeros((len(x), m)), np.eye(m)

    ekf, rng = _random_filter(21)
    monkeypatch.setattr(kern, "joseph_update", broken)
    x0, P0 = ekf.full_state()
    idx, Hc, nu, Rn = _random_measurement(ekf, rng)
    x1, P1, K, S = _dense_update(x0, P0, idx, Hc, nu, Rn)
    ekf.update(idx, Hc, nu, Rn)
    x, P = ekf.full_state()
    with pytest.raises(AssertionError, match="state did not move"):
        _check_moved(x0, x, K, nu)
    with pytest.raises(AssertionError, match="trace reduction"):
        _check_trace(P0, P, K, S)
    with pytest.raises(AssertionError, match="did not shrink"):
        _check_rank(P0, P, len(nu))
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(P, P1, rtol=1e-10, atol=1e-10)
    # and the same checks pass on the dense oracle's own result (they are not vacuous)
    _information_checks(P0, P1, x0, x1, K, S, nu)


# ------------------------------------------------------------------------------------------ prediction
def _dense_predict(x, P, nv, dt, R, q, C, yaw_bias_rw=0.0, i_yaw=-1):
    """``x+ = f(x)``, ``P+ = F P F^T + Q`` of the constant-velocity model with white body-frame acceleration
    of spectral densities ``q**2`` and AHRS attitude noise ``C`` (world-frame rotation vector)."""
    n = len(x)
    b = x[i_yaw] if i_yaw >= 0 else 0.0
    Rt = kern.rot_z(-b) @ R  # true attitude: AHRS corrected by the yaw bias
    v = x[3:6]
    d = Rt @ v * dt
    x1 = x.copy()
    x1[0:3] += d
    F = np.eye(n)
    F[0:3, 3:6] = Rt * dt
    if i_yaw >= 0:
        F[0:3, i_yaw] = -np.cross([0.0, 0.0, 1.0], d)  # d/db Rz(-b) u = -e_z x (Rz(-b) u)
    Qb = np.diag(np.asarray(q, dtype=float) ** 2)
    Q = np.zeros((n, n))
    Q[0:3, 0:3] = Rt @ Qb @ Rt.T * dt**3 / 3 + kern.skew(d) @ C @ kern.skew(d).T
    Q[0:3, 3:6] = Rt @ Qb * dt**2 / 2
    Q[3:6, 0:3] = Q[0:3, 3:6].T
    Q[3:6, 3:6] = Qb * dt
    if i_yaw >= 0:
        Q[i_yaw, i_yaw] = yaw_bias_rw**2 * dt
    return x1, F @ P @ F.T + Q


@pytest.mark.parametrize("yaw_bias", [False, True])
def test_predict_equals_dense_form_with_landmarks(yaw_bias):
    """Catches a prediction that forgets the vehicle-landmark cross-covariances (only the vehicle block
    propagated), uses ``R^T`` for ``R``, the wrong powers of ``dt`` in ``Q``, drops the attitude noise, or
    has the yaw-bias column of ``F`` with the wrong sign."""
    ekf, rng = _random_filter(30 + yaw_bias, yaw_bias=yaw_bias)
    for _ in range(25):
        x, P = ekf.full_state()
        dt = float(rng.uniform(0.01, 0.5))
        R = rotation_from_rpy(*rng.uniform(-np.pi, np.pi, 3) * [0.2, 0.2, 1.0])
        q = tuple(rng.uniform(0.001, 0.1, 3))
        A = rng.normal(size=(3, 3)) * 0.01
        C = A @ A.T
        x1, P1 = _dense_predict(x, P, ekf.n_v, dt, R, q, C, 0.003, ekf.i_yaw)
        ekf.predict(dt, R, velocity_rw=q, attitude_cov_world=C, yaw_bias_rw=0.003)
        x, P = ekf.full_state()
        np.testing.assert_allclose(x, x1, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(P, P1, rtol=1e-10, atol=1e-12)


def test_constant_velocity_random_walk_analytic_with_landmark():
    """Catches errors in the continuous-time noise integration or in the cross-covariance propagation:
    starting from a covariance with position, velocity and a landmark correlated with the velocity, after
    steps of total duration ``t`` (constant attitude) the exact solution is
    ``Ppp = Ppp0 + t (R Pvp0 + Ppv0 R^T) + t^2 R Pvv0 R^T + q^2 t^3/3``, ``Ppv = Ppv0 + t R Pvv0 + q^2 t^2/2 R``,
    ``Pvv = Pvv0 + q^2 t``, ``Ppl = Ppl0 + t R Pvl0``, ``Pvl``, ``Pll`` unchanged; mean ``p + R v t``."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(6, 6)) * 0.1
    ekf = SemanticEkf([1.0, 2.0, -1.0], [0.4, -0.1, 0.05], A @ A.T + 1e-3 * np.eye(6))
    G = np.zeros((6, 6))
    G[0:3, 0:3] = np.eye(3)
    G[0:3, 3:6] = rng.normal(size=(3, 3))  # landmark correlated with the velocity
    ekf.add_landmark(np.r_[5.0, 0.0, 2.0, 0.0, 0.0, 0.0], G, 0.01 * np.eye(6), label="valve", stamp_s=0.0)
    x0, P0 = ekf.full_state()
    R = rotation_from_rpy(0.05, -0.1, 2.5)
    q = 0.03
    dts = rng.uniform(0.01, 0.3, 60)
    for dt in dts:
        ekf.predict(float(dt), R, velocity_rw=q)
    t = dts.sum()
    x, P = ekf.full_state()
    p, v, l = slice(0, 3), slice(3, 6), slice(6, 12)
    I3 = np.eye(3)
    Ppp = (P0[p, p] + t * (R @ P0[v, p] + P0[p, v] @ R.T) + t**2 * R @ P0[v, v] @ R.T + q**2 * t**3 / 3 * I3)
    np.testing.assert_allclose(P[p, p], Ppp, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(P[p, v], P0[p, v] + t * R @ P0[v, v] + q**2 * t**2 / 2 * R, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(P[v, v], P0[v, v] + q**2 * t * I3, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(P[p, l], P0[p, l] + t * R @ P0[v, l], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(P[v, l], P0[v, l], rtol=0, atol=1e-15)
    np.testing.assert_allclose(P[l, l], P0[l, l], rtol=0, atol=1e-15)
    np.testing.assert_allclose(x[p], x0[p] + R @ x0[v] * t, rtol=1e-12)
    np.testing.assert_array_equal(x[3:], x0[3:])


def test_inflate_adds_exactly_q():
    """Catches an inflation applied to the wrong block (global vs active indices) or scaled: only the chosen
    block changes, by ``Q`` exactly."""
    ekf, rng = _random_filter(7)
    x0, P0 = ekf.full_state()
    idx = ekf.landmarks[1].offset + np.arange(3, 6)
    Q = np.diag([0.1, 0.2, 0.3])
    ekf.inflate(idx, Q)
    x, P = ekf.full_state()
    expected = P0.copy()
    expected[np.ix_(idx, idx)] += Q
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_allclose(P, expected, rtol=0, atol=1e-15)
