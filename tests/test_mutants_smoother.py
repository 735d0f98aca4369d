"""Tests that kill surviving mutants of ``semslam/slam/smoother.py`` (benchmarks/mutation.py).

Oracles: numpy's pseudo-inverse, and the invariance of a linear run under a shift of its angles (the same
filter with the landmark's roll and yaw and the AHRS yaw bias 90 degrees away from the +-pi wrap must give the
same smoothed vehicle states).
"""

from __future__ import annotations

import numpy as np
import pytest

from semslam.slam import _ekf_kernels as kern
from semslam.slam.ekf import SemanticEkf
from semslam.slam.smoother import RtsRecorder, SmoothedStates, _gain, _pinv_psd


def _run(shift, yaw_bias):
    """A run whose landmark angles start 0.002 rad above -pi and yaw bias 0.06 rad below +pi (``shift`` = 0: they
    cross the wrap) or ``shift`` further inside. The
    measurements are linear with constant innovations and the AHRS reads ``Rz(b0)``, so the run does not depend
    on the absolute angles: only the wrap can make two shifts differ."""
    a0 = -np.pi + 0.002 + shift
    b0 = np.pi - 0.06 - shift
    nv = 6 + yaw_bias
    ekf = SemanticEkf(np.array([0.5, -0.2, 1.0]), np.array([0.3, 0.1, 0.0]), np.eye(nv) * 0.02, yaw_bias=yaw_bias)
    if yaw_bias:
        ekf.xa[ekf.i_yaw] = b0
    G = np.zeros((6, nv))
    G[0:3, 0:3] = np.eye(3)
    G[3:6, 0:3] = 0.2 * np.eye(3)
    ekf.add_landmark(np.array([2.0, 1.0, 3.0, a0, 0.1, a0]), G, np.eye(6) * 0.01, label="valve", stamp_s=0.0)
    off = ekf.landmarks[0].offset
    rec = RtsRecorder(n_keep=nv)
    ekf.recorder = rec
    R_ahrs = kern.rot_z(b0) if yaw_bias else np.eye(3)
    for _ in range(6):
        ekf.predict(1.0, R_ahrs, velocity_rw=0.05, yaw_bias_rw=0.02)
        rec.mark(ekf)
        ekf.update(np.array([0, off]), np.array([[1.0, -1.0]]), np.array([0.03]), np.array([[0.01]]))
        idx = np.array([off + 3, off + 5, 1] + ([ekf.i_yaw] if yaw_bias else []))
        Hc = np.zeros((2 + yaw_bias, len(idx)))
        Hc[0, 0] = Hc[1, 1] = 1.0
        Hc[0, 2] = Hc[1, 2] = 0.3
        if yaw_bias:
            Hc[2, 3] = 1.0
        ekf.update(idx, Hc, np.full(2 + yaw_bias, 0.02), np.eye(2 + yaw_bias) * 1e-4)
    rec.mark(ekf)
    final = ekf.landmark_pose(0)
    return rec.smooth(ekf), final, (ekf.yaw_bias_rad() if yaw_bias else 0.0)


@pytest.mark.parametrize("yaw_bias", [False, True])
def test_smoothing_across_the_angle_wrap_equals_smoothing_away_from_it(yaw_bias):
    """Catches angle differences in the backward pass that are not wrapped for every angle state (the landmark
    roll, pitch, yaw and the yaw bias; e.g. a mask that skips the landmarks, starts at the pitch, or leaves out
    the yaw bias): a difference of ~2 pi instead of ~0.04 rad would throw the earlier smoothed states off."""
    sm_wrap, lm_wrap, b_wrap = _run(0.0, yaw_bias)
    sm_away, lm_away, b_away = _run(np.pi / 2, yaw_bias)
    assert lm_wrap[3] > np.pi - 0.1 and lm_wrap[5] > np.pi - 0.1     # roll and yaw did cross the wrap
    assert lm_away[3] == pytest.approx(lm_wrap[3] - 2 * np.pi + np.pi / 2, abs=1e-9)
    assert lm_away[5] == pytest.approx(lm_wrap[5] - 2 * np.pi + np.pi / 2, abs=1e-9)
    if yaw_bias:
        assert b_wrap < -np.pi + 0.1 and b_away == pytest.approx(b_wrap + 2 * np.pi - np.pi / 2, abs=1e-9)
    np.testing.assert_allclose(sm_wrap.x[:, :6], sm_away.x[:, :6], atol=1e-9)
    np.testing.assert_allclose(sm_wrap.P[:, :6, :6], sm_away.P[:, :6, :6], atol=1e-12)


def test_pinv_psd_equals_numpy_pinv_on_a_singular_covariance():
    """Catches a wrong symmetrisation or scale in the smoother's pseudo-inverse (``1.5 (P + P^T)``, ``P - P^T``):
    on a rank-deficient PSD matrix it equals ``numpy.linalg.pinv``."""
    rng = np.random.default_rng(0)
    A = rng.normal(size=(5, 3))
    P = A @ A.T
    np.testing.assert_allclose(_pinv_psd(P), np.linalg.pinv(P, rcond=1e-12, hermitian=True), atol=1e-10)
    np.testing.assert_allclose(_pinv_psd(np.diag([4.0, 2.0, 0.0])), np.diag([0.25, 0.5, 0.0]), atol=1e-15)


def test_gain_falls_back_to_the_pseudo_inverse_when_cholesky_fails():
    """Catches a fallback that does not catch Cholesky's ``LinAlgError`` (a prior covariance with unit diagonal
    but singular, two perfectly correlated states): the gain is ``PFt pinv(P_pr)``, and on a regular ``P_pr`` it
    is ``PFt inv(P_pr)``."""
    P_pr = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 2.0]])
    PFt = np.arange(9.0).reshape(3, 3)
    np.testing.assert_allclose(_gain(PFt, P_pr), PFt @ np.linalg.pinv(P_pr), atol=1e-12)
    P_ok = np.array([[2.0, 0.5, 0.0], [0.5, 1.0, 0.2], [0.0, 0.2, 3.0]])
    np.testing.assert_allclose(_gain(PFt, P_ok), PFt @ np.linalg.inv(P_ok), atol=1e-12)


def test_smoothed_states_are_compared_by_identity():
    """Catches ``eq=True`` on ``SmoothedStates`` (arrays inside: ``==`` would be ambiguous, and the class would
    stop being hashable)."""
    a = SmoothedStates(np.zeros((1, 6)), np.zeros((1, 6, 6)))
    b = SmoothedStates(np.zeros((1, 6)), np.zeros((1, 6, 6)))
    assert a != b and a == a and len({a, b}) == 2


def test_recorder_defaults():
    """Catches a changed default memory budget (512 MB) or kept-state count (6: vehicle position and velocity)."""
    rec = RtsRecorder()
    assert rec.max_bytes == 512e6 and rec.n_keep == 6 and rec.status == "recording" and rec.active
