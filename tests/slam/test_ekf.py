"""The semantic EKF (``semslam/slam/ekf.py``) and its kernels (``_ekf_kernels.py``): analytic dead-reckoning
covariance, compressed == dense EKF, angle wrap, gimbal lock, SPD over 1e5 updates, symmetric objects, the
Gauss-Markov DVL biases, the recorded pitch flips, the heading-constrained update, the accessors' defaults.

Oracles: closed forms of the models (Gauss-Markov bias, Euler-angle re-parametrisation), scipy's rotations and
dense recomputations of ``(x, P)``, never the kernel under test."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.detection import Detection
from semslam.geometry import RigidTransform, rotation_from_rpy, rotations_from_rpy
from semslam.slam import _ekf_kernels as kern
from semslam.slam.association import innovation, measurement_from_detection
from semslam.slam.ekf import SemanticEkf
from semslam.slam.smoother import RtsRecorder
from semslam.symmetry import Symmetry


def _ekf(n_landmarks=0, seed=0, yaw_bias=False):
    rng = np.random.default_rng(seed)
    nv = 7 if yaw_bias else 6
    P0 = np.diag([0.1, 0.2, 0.05, 0.01, 0.02, 0.01, 0.003][:nv])
    ekf = SemanticEkf([1.0, 2.0, 3.0], [0.3, 0.0, 0.0], P0, yaw_bias=yaw_bias)
    for i in range(n_landmarks):
        G = np.zeros((6, nv))
        G[0:3, 0:3] = np.eye(3)
        A = rng.normal(size=(6, 6)) * 0.05
        ekf.add_landmark(np.r_[rng.uniform(-5, 5, 3), rng.uniform(-1, 1, 3)], G, A @ A.T + 1e-3 * np.eye(6),
                         label="a", stamp_s=0.0)
    return ekf


def test_dead_reckoning_covariance_matches_analytic():
    sp, sv, q = 0.1, 0.05, 0.02
    P0 = np.diag([sp**2] * 3 + [sv**2] * 3)
    ekf = SemanticEkf(np.zeros(3), [0.5, 0.0, 0.0], P0)
    yaw = 0.7
    R = rotation_from_rpy(0.0, 0.0, yaw)
    dts = np.random.default_rng(1).uniform(0.01, 0.2, 200)
    for dt in dts:
        ekf.predict(dt, R, velocity_rw=q)
    t = dts.sum()
    # continuous white acceleration (body frame, rotated by a constant R): exact for any step sizes
    Ppp = sp**2 * np.eye(3) + sv**2 * t**2 * np.eye(3) + q**2 * t**3 / 3 * np.eye(3)
    Ppv = sv**2 * t * R + q**2 * t**2 / 2 * R
    Pvv = sv**2 * np.eye(3) + q**2 * t * np.eye(3)
    np.testing.assert_allclose(ekf.Paa[0:3, 0:3], Ppp, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ekf.Paa[0:3, 3:6], Ppv, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ekf.Paa[3:6, 3:6], Pvv, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ekf.xa[0:3], R @ [0.5 * t, 0.0, 0.0], rtol=1e-12)


def test_attitude_noise_enters_process_noise():
    ekf = SemanticEkf(np.zeros(3), [1.0, 0.0, 0.0], np.zeros((6, 6)))
    C = np.diag([0.0, 0.0, 0.01])  # yaw only
    ekf.predict(1.0, np.eye(3), velocity_rw=0.0, attitude_cov_world=C)
    # displacement d = (1, 0, 0): yaw error moves the vehicle sideways: var_y = |d|^2 * 0.01
    np.testing.assert_allclose(ekf.Paa[0:3, 0:3], np.diag([0.0, 0.01, 0.0]), atol=1e-15)


def _random_ops(ekf, rng, n, active_ids):
    for _ in range(n):
        ekf.predict(rng.uniform(0.05, 0.2), rotation_from_rpy(*rng.uniform(-0.3, 0.3, 3)), velocity_rw=0.05,
                    attitude_cov_world=np.eye(3) * 1e-4)
        k = rng.integers(3)
        if k == 0:
            ekf.update(np.arange(3, 6), np.eye(3), rng.normal(0, 0.01, 3), np.eye(3) * 1e-4)
        elif k == 1:
            ekf.update(np.array([2]), np.ones((1, 1)), rng.normal(0, 0.02, 1), np.array([[4e-4]]))
        else:
            j = int(rng.choice(active_ids))
            off = ekf.landmarks[j].offset
            idx = np.r_[np.arange(ekf.n_v), off + np.arange(6)]
            H = rng.normal(size=(6, len(idx)))
            ekf.update(idx, H, rng.normal(0, 0.05, 6), np.eye(6) * 0.01)


@pytest.mark.parametrize("yaw_bias", [False, True])
def test_compressed_update_equals_dense(yaw_bias):
    dense, comp = _ekf(12, yaw_bias=yaw_bias), _ekf(12, yaw_bias=yaw_bias)
    comp.set_active_landmarks([3, 7])
    assert comp.compressed and not dense.compressed
    _random_ops(dense, np.random.default_rng(5), 60, [3, 7])
    _random_ops(comp, np.random.default_rng(5), 60, [3, 7])
    # exact views of passive states before the flush
    np.testing.assert_allclose(comp.landmark_cov(5), dense.landmark_cov(5), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(comp.landmark_pose(5), dense.landmark_pose(5), rtol=1e-9, atol=1e-12)
    x1, P1 = dense.full_state()
    x2, P2 = comp.full_state()
    np.testing.assert_allclose(x2, x1, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(P2, P1, rtol=1e-8, atol=1e-11)


def _dense_joseph(P, x, loc, Hc, nu, Rn):
    """Textbook update (explicit inverse, dense H, Joseph form): the oracle of the kernel's first steps."""
    H = np.zeros((len(nu), len(x)))
    H[:, loc] = Hc
    S = H @ P @ H.T + Rn
    K = P @ H.T @ np.linalg.inv(S)
    IKH = np.eye(len(x)) - K @ H
    return x + K @ nu, IKH @ P @ IKH.T + K @ Rn @ K.T, K


def test_covariance_stays_spd_over_1e5_updates():
    """1e5 ill-conditioned updates (1e-6 noise against metre-level priors) keep P symmetric positive definite.
    Also catches an update that does nothing (K = 0, which would trivially stay SPD): the first updates move
    the state by ``K nu`` and match the dense Joseph form, and at the end the measured directions have the
    variance the 1e-6 measurements give (a no-op update leaves them at the prior's 1e-2)."""
    # straight through the filter's kernels (the ones SemanticEkf.predict / update call), on the filter's own
    # active block: a cheap loop
    ekf = _ekf(2, seed=3)
    P, x = ekf.Paa, ekf.xa
    P_prior = P.copy()
    rng = np.random.default_rng(11)
    n_steps = 100_000 // 3 + 1
    R_wv = rotations_from_rpy(np.column_stack([np.zeros((n_steps, 2)), rng.uniform(-np.pi, np.pi, n_steps)]))
    noise = rng.normal(0.0, 1e-3, (n_steps, 7))
    R_dvl, R_dep, R_lm = np.eye(3) * 1e-6, np.array([[1e-6]]), np.eye(3) * 1e-6
    H_dvl, H_dep, H_lm = np.eye(3), np.ones((1, 1)), np.hstack([-np.eye(3), np.eye(3)])
    loc_dvl, loc_dep = np.arange(3, 6), np.array([2])
    loc_lm = [np.r_[0, 1, 2, np.arange(3) + lm.offset].astype(np.intp) for lm in ekf.landmarks]
    no_att = np.zeros((3, 3))
    for i in range(n_steps):
        kern.predict_vehicle(P, x, R_wv[i], 0.05, np.full(3, 1e-8), no_att, 6, 0.0, -1, -1, 1.0, 0.0, 1.0, 0.0)
        if i < 3:  # the oracle on the first steps: each update equals the dense textbook one
            for loc, H, nu, Rn in ((loc_dvl, H_dvl, noise[i, 0:3], R_dvl), (loc_dep, H_dep, noise[i, 3:4], R_dep),
                                   (loc_lm[i % 2], H_lm, noise[i, 4:7], R_lm)):
                x_exp, P_exp, K_exp = _dense_joseph(P.copy(), x.copy(), loc, H, nu, Rn)
                x_before = x.copy()
                K, _ = kern.joseph_update(P, x, loc, H, nu, Rn)
                np.testing.assert_allclose(x - x_before, K_exp @ nu, rtol=1e-8, atol=1e-12)
                np.testing.assert_allclose(K, K_exp, rtol=1e-8, atol=1e-12)
                np.testing.assert_allclose(P, P_exp, rtol=1e-7, atol=1e-12)
            continue
        kern.joseph_update(P, x, loc_dvl, H_dvl, noise[i, 0:3], R_dvl)
        kern.joseph_update(P, x, loc_dep, H_dep, noise[i, 3:4], R_dep)
        kern.joseph_update(P, x, loc_lm[i % 2], H_lm, noise[i, 4:7], R_lm)
    assert 3 * n_steps >= 100_000
    assert np.array_equal(P, P.T)
    assert np.isfinite(P).all() and np.isfinite(x).all()
    w = np.linalg.eigvalsh(P)
    assert w.min() > 0
    # the information went in: velocity and depth measured to 1e-6 (variance 1e-6 each time, ~33,000 times)
    assert np.diag(P)[3:6].max() < 1e-6 and P[2, 2] < 1e-6
    assert np.diag(P_prior)[3:6].min() >= 1e-2 and P_prior[2, 2] >= 0.05
    # and each landmark's position relative to the vehicle, l - p, to the same level
    for lm in ekf.landmarks:
        D = np.hstack([-np.eye(3), np.zeros((3, 3)), np.eye(3), np.zeros((3, 3))])
        rel = np.r_[0:6, lm.offset + np.arange(6)]
        assert np.linalg.eigvalsh(D @ P[np.ix_(rel, rel)] @ D.T).max() < 1e-6
    # and the filter object still agrees with what the kernels did to its active block
    assert ekf.Paa is P and np.linalg.eigvalsh(ekf.cov(np.arange(ekf.n))).min() > 0


def _single_landmark_filter(rpy_landmark):
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-4)
    G = np.zeros((6, 6))
    G[0:3, 0:3] = np.eye(3)
    ekf.add_landmark(np.r_[[2.0, 0.0, 1.0], rpy_landmark], G, np.diag([1e-2] * 3 + [0.05**2] * 3), label="a", stamp_s=0.0)
    return ekf


def _detection(R_so, t_so, rot_sigma=0.02, label="a"):
    E_inv = kern.world_rate_to_rpy(RigidTransform.from_rotation_translation(R_so, t_so).as_rpy())
    cov = np.zeros((6, 6))
    cov[0:3, 0:3] = np.eye(3) * 1e-4
    cov[3:6, 3:6] = E_inv @ (np.eye(3) * rot_sigma**2) @ E_inv.T
    return Detection(label, 0.0, RigidTransform.from_rotation_translation(R_so, t_so), 0.5 * (cov + cov.T))


def test_yaw_wrap_at_pi():
    ekf = _single_landmark_filter([0.0, 0.0, np.pi - 0.01])
    R_meas = rotation_from_rpy(0.0, 0.0, -np.pi + 0.01)  # 0.02 rad away across the +-pi cut
    meas = measurement_from_detection(_detection(R_meas, [2.0, 0.0, 1.0]), RigidTransform.identity())
    inn = innovation(ekf, 0, meas, np.eye(3), None)
    assert abs(inn.nu[5]) == pytest.approx(0.02, abs=1e-9)
    ekf.update(inn.idx, inn.H, inn.nu, inn.R)
    yaw = ekf.landmark_pose(0)[5]
    assert -np.pi <= yaw < np.pi
    assert min(abs(yaw - np.pi), abs(yaw + np.pi)) < 0.02
    inn_rpy = innovation(ekf, 0, meas, np.eye(3), None, orientation_innovation="rpy")
    assert np.abs(inn_rpy.nu[3:]).max() < 0.02


def test_pitch_near_90_degrees_gives_no_nan():
    ekf = _single_landmark_filter([0.3, np.radians(89.95), 1.0])
    for pitch_deg in (90.0, 89.0, 90.0, 91.0):
        R_meas = rotation_from_rpy(0.2, np.radians(pitch_deg), 1.1)
        det = _detection(R_meas, [2.0, 0.0, 1.0])
        meas = measurement_from_detection(det, RigidTransform.identity())
        for mode in ("rotvec", "rpy"):
            inn = innovation(ekf, 0, meas, np.eye(3), np.eye(3) * 1e-6, orientation_innovation=mode)
            assert np.isfinite(inn.nu).all() and np.isfinite(inn.S).all() and np.isfinite(inn.d2_pose)
        ekf.update(inn.idx, inn.H, inn.nu, inn.R)
        x, P = ekf.full_state()
        assert np.isfinite(x).all() and np.isfinite(P).all()
        assert abs(x[6 + 4]) <= np.pi / 2 + 1e-12
        assert np.linalg.eigvalsh(P).min() > 0
    # the estimate is still the measured orientation (equivalent rotation)
    R_est = rotation_from_rpy(*ekf.landmark_pose(0)[3:])
    assert np.linalg.norm(kern.so3_log(R_est @ R_meas.T)) < 0.05


def test_symmetric_object_rotation_about_axis_does_not_move_landmark():
    axis = np.array([0.0, 0.0, 1.0])
    sym = Symmetry("continuous", axis_object=axis)
    ekf = _single_landmark_filter([0.0, 0.0, 0.4])
    R_l = rotation_from_rpy(0.0, 0.0, 0.4)
    # measured orientation: rotated 1.5 rad about the symmetry axis, plus a small tilt of 0.03 rad about x
    R_meas = kern.axis_rotation([1.0, 0.0, 0.0], 0.03) @ R_l @ kern.axis_rotation(axis, 1.5)
    det = _detection(R_meas, [2.0, 0.0, 1.0])
    meas = measurement_from_detection(det, RigidTransform.identity(), symmetry=sym)
    assert meas.unobservable_axes_vehicle.shape == (1, 3)
    inn = innovation(ekf, 0, meas, np.eye(3), None)
    assert inn.dof_pose == 5
    ekf.update(inn.idx, inn.H, inn.nu, inn.R)
    R_new = rotation_from_rpy(*ekf.landmark_pose(0)[3:])
    dR = kern.so3_log(R_new @ R_l.T)
    assert abs(dR[2]) < 1e-3          # no rotation about the (world z) symmetry axis
    assert dR[0] > 0.01               # the observable tilt was applied


def test_so3_exp_and_rot_z_match_scipy():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(2)
    ws = np.vstack([rng.normal(0.0, 2.0, (50, 3)), [[1e-9, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, np.pi]]])
    for w in ws:
        np.testing.assert_allclose(kern.so3_exp(w), Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    for a in rng.uniform(-4.0, 4.0, 10):
        np.testing.assert_allclose(kern.rot_z(a), Rotation.from_euler("z", a).as_matrix(), atol=1e-14)


def test_anisotropic_body_acceleration_noise_matches_analytic():
    q = np.array([0.05, 0.01, 0.02])
    ekf = SemanticEkf(np.zeros(3), [0.5, 0.0, 0.0], np.zeros((6, 6)))
    R = rotation_from_rpy(0.1, -0.2, 0.7)
    dts = np.random.default_rng(3).uniform(0.01, 0.2, 100)
    for dt in dts:
        ekf.predict(dt, R, velocity_rw=q)
    t = dts.sum()
    Qb = np.diag(q**2)
    np.testing.assert_allclose(ekf.Paa[0:3, 0:3], R @ Qb @ R.T * t**3 / 3, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(ekf.Paa[0:3, 3:6], R @ Qb * t**2 / 2, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(ekf.Paa[3:6, 3:6], Qb * t, rtol=1e-10, atol=1e-15)


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
    _, P_po, x_pr, P_pr, F, _ = rec._nodes[len(rec._nodes) - 1]
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


@pytest.mark.parametrize("angle", [1e-9, 3e-7, 9e-7, 2e-6, 1e-3, 1.0, 3.0, np.pi - 2e-4, np.pi - 2e-5, np.pi - 1e-9])
def test_so3_log_matches_scipy_at_all_scales(angle):
    """Catches a wrong small-angle branch of ``so3_log`` (e.g. ``1.5 v`` for ``0.5 v``: below 1e-6 rad the
    rotation vector is half the skew part of R) and errors in the general and near-pi branches: the rotation
    vector of ``Rotation.from_rotvec(w)`` must be ``w`` (scipy), for angles from 1e-9 rad to pi."""
    rng = np.random.default_rng(int(angle * 1e9) % 2**32)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    w = angle * u
    R = Rotation.from_rotvec(w).as_matrix()
    # within 1e-4 rad of pi the axis comes from the symmetric part of R: full precision there too
    rtol = 1e-6
    np.testing.assert_allclose(kern.so3_log(R), Rotation.from_matrix(R).as_rotvec(), rtol=rtol, atol=1e-15)
    np.testing.assert_allclose(kern.so3_log(R), w, rtol=rtol, atol=1e-15)


@pytest.mark.parametrize("pitch_deg", [-80.0, -30.0, 0.0, 45.0, 79.0])
def test_world_rate_to_rpy_inverts_rpy_to_world_rate(pitch_deg):
    """Catches a wrong inverse of the Euler-rate matrix (a sign, e.g. ``+sin(yaw)`` in the second row) and a
    clamp of ``cos(pitch)`` that bites away from gimbal lock (default ``min_cos_pitch`` must be tiny, 1e-3):
    ``world_rate_to_rpy(rpy) @ rpy_to_world_rate(rpy) = I`` wherever the filter uses it (|pitch| <= 80 deg), and
    ``rpy_to_world_rate`` maps Euler-angle rates to the world angular velocity (finite differences of scipy)."""
    rpy = np.array([0.3, np.radians(pitch_deg), 2.5])
    E = kern.rpy_to_world_rate(rpy)
    np.testing.assert_allclose(kern.world_rate_to_rpy(rpy) @ E, np.eye(3), atol=1e-12)
    h = 1e-7
    for k in range(3):   # w = Log(R(rpy + h e_k) R(rpy)^T) / h  (world frame, left perturbation)
        d = np.zeros(3)
        d[k] = h
        R1 = Rotation.from_euler("ZYX", (rpy + d)[::-1]).as_matrix()
        R0 = Rotation.from_euler("ZYX", rpy[::-1]).as_matrix()
        np.testing.assert_allclose(Rotation.from_matrix(R1 @ R0.T).as_rotvec() / h, E[:, k], atol=1e-6)


def test_world_rate_to_rpy_clamps_only_near_gimbal_lock():
    """Catches a clamp threshold that is not the argument: at pitch 90 deg (cos = 6e-17) the result is finite and
    equals the formula with ``cos(pitch)`` replaced by ``min_cos_pitch``."""
    rpy = np.array([0.0, np.pi / 2, 0.0])
    M = kern.world_rate_to_rpy(rpy, min_cos_pitch=1e-3)
    assert np.isfinite(M).all()
    assert M[0, 0] == pytest.approx(1.0 / 1e-3) and M[2, 0] == pytest.approx(1.0 / 1e-3)


@pytest.mark.parametrize("cols", [0, 1, 2, 5])
def test_subtract_outer_inplace_equals_dense(cols):
    """Catches an early return on the wrong shape (e.g. on a single-column ``W``, the usual rank-one downdate):
    ``P`` must become ``P - W W^T`` in place for any number of columns (nothing to do for none)."""
    rng = np.random.default_rng(cols)
    A = rng.normal(size=(7, 7))
    P = np.ascontiguousarray(A @ A.T + 7 * np.eye(7))
    W = rng.normal(size=(7, cols))
    expected = P - W @ W.T
    ref = P
    kern.subtract_outer_inplace(P, W)
    assert P is ref
    np.testing.assert_allclose(P, expected, rtol=1e-13, atol=1e-13)
