"""Tests that kill surviving mutants of ``semslam/slam/ekf.py`` (benchmarks/mutation.py).

Oracles: closed forms of the models (Gauss-Markov bias, Euler-angle re-parametrisation) and dense
recomputations of ``(x, P)``.
"""

from __future__ import annotations

import numpy as np
import pytest

from semslam.slam.ekf import SemanticEkf
from semslam.slam.smoother import RtsRecorder


def test_vehicle_position_cov_is_the_3x3_position_block():
    """Catches a wrong slice of the vehicle position covariance (e.g. 3 x 4): it is ``P[0:3, 0:3]`` of the full
    state, a copy."""
    rng = np.random.default_rng(0)
    A = rng.normal(size=(6, 6))
    ekf = SemanticEkf(np.ones(3), np.zeros(3), A @ A.T + np.eye(6))
    C = ekf.vehicle_position_cov()
    _, P = ekf.full_state()
    assert C.shape == (3, 3)
    np.testing.assert_array_equal(C, P[0:3, 0:3])
    C[0, 0] = -1.0
    assert ekf.vehicle_position_cov()[0, 0] == P[0, 0]


def test_dvl_biases_are_decaying_gauss_markov_processes():
    """Catches a growing instead of decaying DVL bias or slope bias (``exp(+dt / tau)``) or a wrong noise gain:
    over one prediction of ``dt`` each bias mean is multiplied by ``a = exp(-dt / tau)`` and its variance becomes
    ``a^2 P + sigma^2 (1 - a^2)`` (first-order Gauss-Markov, closed form; the slope bias is driven on a slope)."""
    sigma, tau, s_sigma, s_tau, dt = 0.02, 50.0, 0.03, 20.0, 2.0
    P0 = np.eye(14) * 0.01
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), P0, dvl_calibration=True, dvl_bias_sigma_mps=sigma,
                      dvl_bias_tau_s=tau, dvl_slope_bias_sigma_mps=s_sigma, dvl_slope_bias_tau_s=s_tau)
    cal = ekf.indices("dvl_calibration")
    ib, islope = cal[:3], cal[3:6]
    ekf.xa[ib] = [0.1, -0.05, 0.02]
    ekf.xa[islope] = [0.04, 0.03, -0.02]
    ekf.predict(dt, np.eye(3), velocity_rw=0.0, dvl_on_slope=True)
    a, a2 = np.exp(-dt / tau), np.exp(-dt / s_tau)
    np.testing.assert_allclose(ekf.xa[ib], a * np.array([0.1, -0.05, 0.02]), rtol=1e-12)
    np.testing.assert_allclose(np.diag(ekf.Paa)[ib], a * a * 0.01 + sigma**2 * (1 - a * a), rtol=1e-12)
    np.testing.assert_allclose(ekf.xa[islope], a2 * np.array([0.04, 0.03, -0.02]), rtol=1e-12)
    np.testing.assert_allclose(np.diag(ekf.Paa)[islope], a2 * a2 * 0.01 + s_sigma**2 * (1 - a2 * a2), rtol=1e-12)


def _two_landmark_filter(pitch1_deg=89.0):
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 0.01)
    G = np.zeros((6, 6))
    G[0:3, 0:3] = np.eye(3)
    G[0:3, 3:6] = 0.3 * np.eye(3)
    rng = np.random.default_rng(1)
    for pose in ([-1.0, 0.5, 2.0, 0.1, 0.2, -0.3], [2.0, 1.0, 3.0, 0.2, np.radians(pitch1_deg), 0.4]):
        B = rng.normal(size=(6, 6)) * 0.1
        ekf.add_landmark(np.array(pose), G, B @ B.T + np.eye(6) * 0.05, label="valve", stamp_s=0.0)
    return ekf


def test_recorded_pitch_flip_explains_the_covariance_change():
    """Catches a wrong state index in the smoother's record of the beyond-90-degrees pitch re-parametrisation
    (``(r, p, y) -> (r + pi, pi - p, y + pi)``, Jacobian -1 on the *pitch* entry of the *flipped* landmark,
    ``nv + 6 j + 4``: not the yaw entry, not ``nv - 6 j + 4``): the transition the recorder stores must map the
    posterior covariance before the flip onto the covariance after it, ``P_after = F P_before F^T`` (no process
    noise in a re-parametrisation). The second landmark (j = 1) is the one that flips."""
    ekf = _two_landmark_filter()
    rec = RtsRecorder(n_keep=6)
    ekf.recorder = rec
    off = ekf.landmarks[1].offset
    ekf.update(np.array([off + 4]), np.array([[1.0]]), np.array([0.2]), np.array([[1e-4]]))
    pitch = ekf.landmark_pose(1)[4]
    assert abs(pitch) < np.pi / 2 and pitch == pytest.approx(np.pi - (np.radians(89.0) + 0.2), abs=0.02)
    rec.mark(ekf)
    x_pr, P_pr, F, _ = rec._prior[-1]
    _, P_po = rec._post[-1]
    J = np.ones(ekf.n)
    J[off + 4] = -1.0
    np.testing.assert_array_equal(np.diag(F), J)
    np.testing.assert_allclose(P_pr, F @ P_po @ F.T, atol=1e-15)


def _dense_update_and_flip(x, P, idx, Hc, nu, Rn, off):
    H = np.zeros((len(nu), len(x)))
    H[:, idx] = Hc
    S = H @ P @ H.T + Rn
    K = P @ H.T @ np.linalg.inv(S)
    IKH = np.eye(len(x)) - K @ H
    x = x + K @ nu
    P = IKH @ P @ IKH.T + K @ Rn @ K.T
    r, p, y = x[off + 3:off + 6]
    assert abs(p) > np.pi / 2
    x[off + 3:off + 6] = [r + np.pi, np.pi - p, y + np.pi]
    x[off + 3:off + 6] = (x[off + 3:off + 6] + np.pi) % (2 * np.pi) - np.pi
    J = np.ones(len(x))
    J[off + 4] = -1.0
    return x, P * np.outer(J, J)


def test_pitch_flip_of_an_active_landmark_in_a_compressed_filter():
    """Catches a pitch re-parametrisation that forgets the compression accumulator (``phi`` row of the flipped
    pitch not negated, or negated only when *not* compressed): with landmark 0 passive, updating landmark 1
    beyond pitch 90 degrees must give the same full ``(x, P)`` as the dense Kalman update followed by the
    re-parametrisation ``(r + pi, pi - p, y + pi)`` with the pitch row and column of ``P`` negated."""
    ekf = _two_landmark_filter()
    x, P = ekf.full_state()
    ekf.set_active_landmarks([1])
    off = ekf.landmarks[1].offset
    idx = np.array([0, 1, off + 4])
    Hc = np.array([[0.3, 0.0, 1.0]])
    nu, Rn = np.array([0.2]), np.array([[1e-4]])
    x1, P1 = _dense_update_and_flip(x, P, idx, Hc, nu, Rn, off)
    ekf.update(idx, Hc, nu, Rn)
    assert ekf.compressed
    xf, Pf = ekf.full_state()
    np.testing.assert_allclose(xf, x1, atol=1e-12)
    np.testing.assert_allclose(Pf, P1, atol=1e-12)


def test_heading_constraint_needs_a_yaw_bias_and_can_be_switched_off():
    """Catches ``and`` for ``or`` in the guard of ``constrain_heading_nullspace``: without a yaw-bias state there
    is nothing to constrain (stays off), and ``enable=False`` switches it off even with a yaw bias."""
    plain = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6))
    plain.constrain_heading_nullspace(True)
    assert not plain.heading_constrained
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(7), yaw_bias=True)
    ekf.constrain_heading_nullspace(True)
    assert ekf.heading_constrained
    ekf.constrain_heading_nullspace(False)
    assert not ekf.heading_constrained


def test_heading_constrained_update_uses_the_projected_jacobian():
    """Catches a wrong projection of the measurement Jacobian in the observability-constrained EKF (``* |u|^2`` for
    ``/ |u|^2``): the update must equal the dense Kalman update with ``H' = H - (H u) u^T / (u^T u)``, ``u`` the
    unobservable direction of the docstring (``dp = e_z x (p - p0) = 0``, ``db = -1``, landmark ``dl = e_z x
    (l - p0)``, ``dyaw = +1``) on the measured columns, and that ``H'`` annihilates it (``H' N = 0``)."""
    ekf = SemanticEkf(np.array([1.0, 2.0, 0.5]), np.zeros(3), np.eye(7) * 0.05, yaw_bias=True)
    G = np.zeros((6, 7))
    G[0:3, 0:3] = np.eye(3)
    ekf.add_landmark(np.array([4.0, -1.0, 3.0, 0.1, 0.2, 0.3]), G, np.eye(6) * 0.02, label="valve", stamp_s=0.0)
    ekf.constrain_heading_nullspace(True)
    x, P = ekf.full_state()
    off = ekf.landmarks[0].offset
    N = np.zeros(ekf.n)
    N[ekf.i_yaw] = -1.0
    N[off:off + 3] = np.cross([0.0, 0.0, 1.0], x[off:off + 3] - x[0:3])
    N[off + 5] = 1.0
    idx = np.r_[np.arange(3), ekf.i_yaw, off + np.arange(6)]
    rng = np.random.default_rng(3)
    Hc = rng.normal(size=(3, len(idx)))
    nu, Rn = rng.normal(size=3) * 0.1, np.eye(3) * 0.01
    u = N[idx]
    Hp = Hc - np.outer(Hc @ u, u) / (u @ u)
    np.testing.assert_allclose(Hp @ u, 0.0, atol=1e-12)
    H = np.zeros((3, ekf.n))
    H[:, idx] = Hp
    S = H @ P @ H.T + Rn
    K = P @ H.T @ np.linalg.inv(S)
    x1 = x + K @ nu
    P1 = (np.eye(ekf.n) - K @ H) @ P
    ekf.update(idx, Hc, nu, Rn)
    xf, Pf = ekf.full_state()
    np.testing.assert_allclose(xf, x1, atol=1e-12)
    np.testing.assert_allclose(Pf, 0.5 * (P1 + P1.T), atol=1e-12)


def test_add_prior_landmarks_signature():
    """Catches a changed signature of ``add_prior_landmarks`` (``stamp_s`` must stay keyword-only and ``labels``
    nameable): calls written against the documented API keep their meaning."""
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6))
    poses, covs = np.zeros((1, 6)), np.eye(6)[None] * 0.1
    with pytest.raises(TypeError):
        ekf.add_prior_landmarks(poses, covs, ["valve"], 5.0)
    ids = ekf.add_prior_landmarks(poses, covs, labels=["valve"], stamp_s=5.0)
    assert ids == [0] and ekf.landmarks[0].first_seen_s == 5.0 and not ekf.is_active(0)


def test_vehicle_accessors_and_defaults():
    """Catches wrong slices or defaults of the small accessors: ``vehicle_position`` is the 3-vector ``x[0:3]``,
    ``yaw_bias_var_rad2`` is 0 without a yaw-bias state, and the slope bias gains no noise unless the prediction
    says the DVL is on a slope (``dvl_on_slope`` defaults to False): its variance only decays, ``a^2 P``."""
    ekf = SemanticEkf(np.array([1.0, 2.0, 3.0]), np.array([0.5, 0.0, 0.0]), np.eye(6))
    np.testing.assert_array_equal(ekf.vehicle_position(), [1.0, 2.0, 3.0])
    assert ekf.yaw_bias_var_rad2() == 0.0 and ekf.yaw_bias_rad() == 0.0
    cal = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(14) * 0.01, dvl_calibration=True,
                      dvl_slope_bias_sigma_mps=0.05, dvl_slope_bias_tau_s=10.0)
    islope = cal.indices("dvl_calibration")[3:6]
    cal.predict(1.0, np.eye(3), velocity_rw=0.0)
    a2 = np.exp(-1.0 / 10.0)
    np.testing.assert_allclose(np.diag(cal.Paa)[islope], a2 * a2 * 0.01, rtol=1e-12)
