"""The association gate under a large AHRS yaw bias (issue 17, helper B): the iterated innovation against a brute-force
minimum and a Monte Carlo of its statistic, the creation gate that keeps near misses out of new landmarks, and the
seeded missions where a 20-degree (and an 8.7-degree) bias used to duplicate the surveyed landmark."""

from __future__ import annotations

import collections
import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from semslam.detection import Detection
from semslam.geometry import RigidTransform, rotation_from_rpy
from semslam.slam import _ekf_kernels as kern
from semslam.slam.association import GateThresholds, innovation, iterated_innovation, measurement_from_detection
from semslam.slam.config import GatingConfig, InitialisationConfig, SlamConfig
from semslam.slam.ekf import SemanticEkf
from semslam.slam.mapping import ObjectMapper

GATE3 = GateThresholds(0.99).threshold(3)
SIG_B = math.radians(20.0)
D_BODY = np.array([1.0, 0.5, 1.0])  # the landmark 1.5 m from the vehicle, in its body frame
COV = np.diag([1e-4] * 3 + [math.radians(2.0) ** 2] * 3)  # detection: 1 cm, 2 degrees


def _scene(sig_b=SIG_B, lm_rpy=(0.2, -0.1, 0.7)):
    """A filter with a yaw-bias state (prior 0 +- sig_b) at the origin, heading 0.3 rad by its AHRS, and a surveyed
    landmark 1.5 m away along the AHRS's body frame: (ekf, R_ahrs, landmark pose)."""
    P0 = np.diag([1e-6] * 3 + [0.05 ** 2] * 3 + [sig_b ** 2])
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), P0, yaw_bias=True)
    R_ahrs = rotation_from_rpy(0.02, -0.03, 0.3)
    pose = np.r_[R_ahrs @ D_BODY, lm_rpy]
    C = np.diag([1e-4] * 3 + [math.radians(0.5) ** 2] * 3)
    ekf.add_prior_landmarks(pose[None], C[None], ["elbow"])
    ekf.set_active_landmarks([0])
    return ekf, R_ahrs, pose


def _meas(x_true, R_ahrs, rng=None):
    """The detection of the landmark from the true state ``[p, v, b, l (6)]`` (noise-free without ``rng``)."""
    R = kern.rot_z(-x_true[6]) @ R_ahrs
    p_vo = R.T @ (x_true[7:10] - x_true[0:3])
    R_vo = R.T @ rotation_from_rpy(*x_true[10:13])
    if rng is not None:
        p_vo = p_vo + rng.normal(0.0, 0.01, 3)
    det = Detection("elbow", 0.0, RigidTransform.from_rotation_translation(R_vo, p_vo), COV)
    return measurement_from_detection(det, RigidTransform.identity())


def _brute_force_d2(ekf, meas, R_ahrs, rows):
    """min over the state of |x - x_hat|^2_P + |z - h(x)|^2_N by scipy's least squares on the whitened residual
    (numeric Jacobian; the exact rotation model for the orientation rows), N the noise at the estimate."""
    lin = innovation(ekf, 0, meas, R_ahrs, None)
    idx = lin.idx
    x0, P = ekf.mean(idx), ekf.cov(idx)
    N = lin.R[:rows, :rows]
    Lp, Ln = np.linalg.cholesky(P), np.linalg.cholesky(N)

    def h(x):
        R = kern.rot_z(-x[6]) @ R_ahrs
        out = [R.T @ (x[7:10] - x[0:3])]
        if rows == 6:
            out.append(-kern.so3_log(R @ meas.R_vehicle_object @ rotation_from_rpy(*x[10:13]).T))
        return np.concatenate(out)

    z = np.r_[meas.p_vehicle_object_m, np.zeros(3)][:rows]

    def res(x):
        return np.r_[np.linalg.solve(Lp, x - x0), np.linalg.solve(Ln, z - h(x))]

    sol = least_squares(res, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return 2.0 * sol.cost, lin


def test_iterated_gate_equals_the_brute_force_minimum_under_a_20_degree_bias():
    """Catches a gate that is first-order in the yaw bias (the bug of issue 17: the linearised S gives the radial
    shift ``r (1 - cos b)`` no variance) and a wrong iterated-EKF fixed point: a noise-free detection under a 20-degree
    bias (prior sigma 20 degrees: a 1-sigma bias) is a perfectly plausible measurement; the iterated statistic
    equals the brute-force minimum of the exact model (position rows exactly; pose rows, whose landmark orientation
    is kept linear, to 1 %), while the linearised one is far outside the 99 % gate."""
    ekf, R_ahrs, pose = _scene()
    x_true = np.r_[np.zeros(6), SIG_B, pose]
    meas = _meas(x_true, R_ahrs)
    it = iterated_innovation(ekf, 0, meas, R_ahrs, None)
    d2_pos, lin = _brute_force_d2(ekf, meas, R_ahrs, 3)
    assert it.d2_position == pytest.approx(d2_pos, rel=1e-6)
    assert d2_pos < GATE3 < lin.d2_position  # linearised: ~20, the oracle ~1
    d2_pose, _ = _brute_force_d2(ekf, meas, R_ahrs, 6)
    assert it.d2_pose == pytest.approx(d2_pose, rel=1e-2)
    assert lin.d2_pose > GateThresholds(0.99).threshold(6) > 4.0 * it.d2_pose
    # the innovation the update uses is referred to the estimate: an update with (H, nu) lands on the iterated state
    Hp, nup, Rp = it.rows("position")
    assert Hp.shape == (3, 13) and nup.shape == (3,)
    ekf.update(it.idx, it.H, it.nu, it.R)
    assert ekf.yaw_bias_rad() == pytest.approx(SIG_B, abs=math.radians(1.0))


def test_iterated_gate_is_the_linear_gate_without_a_yaw_bias_state():
    """Catches the iteration changing the default modes: without a yaw-bias state the model is linear in the
    vehicle and landmark position, and the iterated innovation is :func:`innovation`, bit for bit."""
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-4)
    C = np.diag([1e-4] * 3 + [1e-3] * 3)
    ekf.add_prior_landmarks(np.r_[1.0, 0.5, 1.0, 0.2, -0.1, 0.7][None], C[None], ["elbow"])
    ekf.set_active_landmarks([0])
    det = Detection("elbow", 0.0, RigidTransform.from_rotation_translation(rotation_from_rpy(0.25, -0.1, 0.6),
                                                                           np.array([1.05, 0.45, 1.02])), COV)
    meas = measurement_from_detection(det, RigidTransform.identity())
    a = innovation(ekf, 0, meas, np.eye(3), np.eye(3) * 1e-4)
    b = iterated_innovation(ekf, 0, meas, np.eye(3), np.eye(3) * 1e-4)
    for f in ("H", "nu", "R", "S"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert (a.d2_pose, a.d2_position) == (b.d2_pose, b.d2_position)


def test_mapper_rule_keeps_the_linear_innovation_inside_the_gate_and_iterates_outside():
    """Catches the mapper's rule (``keep_within``) iterating rows whose linearisation is adequate (which would change
    every EKF update) or not iterating the others: a 0.5-degree bias error passes the linear gates with a negligible
    linearisation error and the result is :func:`innovation` bit for bit; a 20-degree one fails the gates, and a
    10-degree one passes the position gate but moves the landmark 2.3 cm off its linearisation (2 noise sigmas,
    ``linear_tol`` 0.2): both take the iterated values (with ``linear_tol`` 10 the 10-degree one stays linear)."""
    thr = {d: GateThresholds(0.99).threshold(d) for d in range(1, 7)}
    ekf, R_ahrs, pose = _scene()
    small = _meas(np.r_[np.zeros(6), math.radians(0.5), pose], R_ahrs)
    lin = innovation(ekf, 0, small, R_ahrs, None)
    kept = iterated_innovation(ekf, 0, small, R_ahrs, None, keep_within=thr)
    assert lin.d2_position <= thr[3] and lin.d2_pose <= thr[6]
    for f in ("H", "nu", "S"):
        np.testing.assert_array_equal(getattr(kept, f), getattr(lin, f))
    np.testing.assert_array_equal(kept.rows("position")[0], lin.H[:3])
    assert (kept.d2_pose, kept.d2_position) == (lin.d2_pose, lin.d2_position)
    large = _meas(np.r_[np.zeros(6), SIG_B, pose], R_ahrs)
    full = iterated_innovation(ekf, 0, large, R_ahrs, None)
    rule = iterated_innovation(ekf, 0, large, R_ahrs, None, keep_within=thr)
    assert rule.d2_position == full.d2_position < thr[3] and rule.d2_pose == full.d2_pose < thr[6]
    np.testing.assert_array_equal(rule.rows("position")[1], full.rows("position")[1])
    mid = _meas(np.r_[np.zeros(6), math.radians(10.0), pose], R_ahrs)
    lin = innovation(ekf, 0, mid, R_ahrs, None)
    full = iterated_innovation(ekf, 0, mid, R_ahrs, None, rows=("position",))
    rule = iterated_innovation(ekf, 0, mid, R_ahrs, None, rows=("position",), keep_within=thr)
    assert lin.d2_position <= thr[3] and rule.d2_position == full.d2_position < 0.5 * lin.d2_position
    loose = iterated_innovation(ekf, 0, mid, R_ahrs, None, rows=("position",), keep_within=thr, linear_tol=10.0)
    assert loose.d2_position == lin.d2_position


def test_monte_carlo_of_the_iterated_gate_statistic_is_chi_square():
    """Catches a gate whose statistic is not calibrated under the nonlinearity (the oracle: states and detections
    drawn from the filter's own model): with a 20-degree yaw-bias prior, 1.5 m range and 1 cm detections, the
    iterated position statistic has mean ~3 (chi-square, 3 dof) and the 99 % gate rejects ~1 % of true
    detections; the linearised gate rejects far more (the seed's rate: ~40 %)."""
    ekf, R_ahrs, pose = _scene()
    idx = np.r_[np.arange(7), ekf.landmarks[0].offset + np.arange(6)]
    x0, P = ekf.mean(idx), ekf.cov(idx)
    L = np.linalg.cholesky(P)
    rng = np.random.default_rng(17)
    it, lin = [], []
    for _ in range(1000):
        x_true = x0 + L @ rng.normal(size=13)
        meas = _meas(x_true, R_ahrs, rng)
        it.append(iterated_innovation(ekf, 0, meas, R_ahrs, None, rows=("position",)).d2_position)
        lin.append(innovation(ekf, 0, meas, R_ahrs, None).d2_position)
    it, lin = np.array(it), np.array(lin)
    assert 2.75 < it.mean() < 3.25  # chi2(3) mean 3, s.e. of 1000 draws 0.077
    assert 0.002 < (it > GATE3).mean() < 0.025  # 1 %, binomial s.e. 0.31 %
    assert (lin > GATE3).mean() > 0.2


def _mapper():
    cfg = SlamConfig(initialisation=InitialisationConfig(consensus_min_observations=1),
                     gating=GatingConfig(candidate_radius_m=100.0))
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-4)
    log = []
    return ObjectMapper(ekf, cfg, "pose", {}, RigidTransform.identity(), lambda **kw: log.append(kw)), ekf, log


def _det(t_so):
    return Detection("valve", 0.9, RigidTransform.from_rotation_translation(np.eye(3), np.asarray(t_so, float)),
                     np.diag([1e-4] * 3 + [1e-3] * 3))


def test_creation_gate_drops_a_near_miss_instead_of_starting_a_duplicate():
    """Catches the two-gate rule missing or inverted: a detection that fails the 99 % association gate of the only
    landmark of its class but passes the creation gate is dropped (``near landmark``) and starts no landmark, even
    with a consensus of one; one beyond the creation gate does start one; the creation gate is never narrower than
    the association gate and defaults to 0.99999."""
    mapper, ekf, log = _mapper()
    assert mapper._thr_create == pytest.approx(GateThresholds(0.99999).threshold(3))
    mapper.process(0.0, [_det([3.0, 0.0, 0.0])], np.eye(3), None)
    assert len(ekf.landmarks) == 1
    S = iterated_innovation(ekf, 0, measurement_from_detection(_det([3.0, 0.0, 0.0]), RigidTransform.identity()),
                            np.eye(3), None).S[:3, :3]
    sy = math.sqrt(S[1, 1])
    log.clear()
    mapper.process(1.0, [_det([3.0, 4.0 * sy, 0.0])], np.eye(3), None)  # d2 ~ 16: between 11.3 and 25.9
    (rec,) = log
    assert rec["reason"] == "near landmark" and rec["accepted"] is False and len(ekf.landmarks) == 1
    log.clear()
    mapper.process(2.0, [_det([3.0, 6.0 * sy, 0.0])], np.eye(3), None)  # d2 ~ 36: another object
    assert len(ekf.landmarks) == 2 and log[-1]["kind"] == "new_landmark"
    wide = ObjectMapper(SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-4),
                        SlamConfig().updated(gate_probability=0.999999, creation_gate_probability=0.9),
                        "pose", {}, RigidTransform.identity(), lambda **kw: None)
    assert wide._thr_create == wide._thr[3]


@pytest.mark.parametrize("bias_deg, sigma_deg, seed", [(20.0, 20.0, 0), (8.739, 3.0, 5)])
@pytest.mark.parametrize("backend", ["ekf", "isam2"])
def test_large_yaw_bias_no_longer_duplicates_the_surveyed_landmark(bias_deg, sigma_deg, seed, backend):
    """The regression of issue 17: a 20-degree AHRS yaw bias (prior 20 degrees), or an 8.7-degree one (a 2.9-sigma
    draw of the mode's 3-degree prior), made the first sightings of the surveyed ``elbow_1`` fail the linearised
    gate; they made a second ``elbow_1`` and the ATE went to 0.52 m / 0.23 m (0.03 m at 2 degrees). Now the
    surveyed landmark takes the updates, the map has the 4 objects once each and the ATE is that of a small bias."""
    from semslam.experiments.montecarlo import make_dataset, truth_run

    mission = make_dataset(seed, yaw_bias_rad=math.radians(bias_deg))
    cfg = SlamConfig().updated(yaw_bias_sigma_rad=math.radians(sigma_deg))
    res = truth_run(mission, "pose+heading", cfg, seed, backend, surveyed=("elbow_1",))
    objects = collections.Counter(lm.matched_object for lm in res.landmarks)
    assert len(res.landmarks) == 4 and max(objects.values()) == 1
    surveyed = res.landmarks[0]
    assert surveyed.matched_object == "elbow_1" and surveyed.n_updates >= 15
    assert res.metrics["ate_rmse_m"] < 0.04
    assert abs(math.degrees(res.yaw_bias_rad[-1]) - bias_deg) < 2.0


@pytest.mark.parametrize("kw, words", [(dict(rows="pose"), ("'rows'", "'pose'")),
                                       (dict(rows=("pos",)), ("'rows'", "('pos',)")),
                                       (dict(max_iterations=0), ("'max_iterations'", ">= 1", "Got 0")),
                                       (dict(max_iterations=2.0), ("'max_iterations'", "Got 2.0")),
                                       (dict(tol=0.0), ("'tol'", "> 0", "Got 0.0")),
                                       (dict(linear_tol=-1.0), ("'linear_tol'", ">= 0", "Got -1.0"))])
def test_iterated_innovation_rejects_bad_arguments(kw, words):
    """Catches unchecked arguments: each bad one raises SlamError naming it and what was given."""
    from semslam.errors import SlamError

    ekf, R_ahrs, pose = _scene()
    meas = _meas(np.r_[np.zeros(6), 0.0, pose], R_ahrs)
    with pytest.raises(SlamError) as exc:
        iterated_innovation(ekf, 0, meas, R_ahrs, None, **kw)
    assert all(w in str(exc.value) for w in words)


@pytest.mark.parametrize("value", [0.5, 1.0, 1.5])
def test_creation_gate_probability_must_be_a_probability(value):
    """Catches an unchecked creation gate: outside (0.5, 1) it raises ConfigError naming the field."""
    from semslam.errors import ConfigError

    with pytest.raises(ConfigError, match="creation_gate_probability.*Got"):
        GatingConfig(creation_gate_probability=value)
