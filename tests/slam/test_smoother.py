"""RTS smoother (``semslam/slam/smoother.py``): exact against fixed-point smoothing by state augmentation on a
linear run, leaves the filter unchanged, improves the trajectory of a real run, says when it is skipped, smooths
across the angle wrap as away from it, and falls back to the pseudo-inverse.

Oracles: fixed-point smoothing, numpy's pseudo-inverse, and the invariance of a linear run under a shift of its
angles (the same filter with the landmark's roll and yaw and the AHRS yaw bias 90 degrees away from the +-pi wrap
must give the same smoothed vehicle states)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.geometry import rotation_from_rpy
from semslam.run.rundir import write_run
from semslam.simulation.synthetic import square_dataset
from semslam.simulation.truth_slam import run_truth_slam
from semslam.slam import _ekf_kernels as kern, SlamConfig
from semslam.slam.ekf import SemanticEkf
from semslam.slam.smoother import _gain, _pinv_psd, RtsRecorder, SmoothedStates


def _script(seed=0, n_steps=120):
    """A linear run (fixed attitude per step, so that the EKF is the exact Kalman filter): predictions,
    velocity and depth updates, a landmark added at step 40 and observed relatively afterwards."""
    rng = np.random.default_rng(seed)
    ops = []
    for k in range(n_steps):
        R = rotation_from_rpy(0.0, 0.0, 0.05 * k)
        ops.append(("predict", rng.uniform(0.05, 0.2), R))
        if k % 3 == 0:
            ops.append(("vel", rng.normal(0.0, 0.01, 3) + [0.3, 0.0, 0.0]))
        if k % 5 == 0:
            ops.append(("depth", rng.normal(2.0, 0.02)))
        if k == 40:
            ops.append(("add", rng.normal(0.0, 0.05, 3)))
        if k > 40 and k % 4 == 0:
            ops.append(("obs", rng.normal(0.0, 0.01, 3), R))
        ops.append(("mark", k))
    return ops


def _run(ops, ekf, clone_at=None):
    """Apply ``ops``; with ``clone_at``, add a noiseless copy of the vehicle position at that mark (the oracle)."""
    for op in ops:
        kind = op[0]
        if kind == "predict":
            ekf.predict(op[1], op[2], velocity_rw=(0.05, 0.01, 0.02))
        elif kind == "vel":
            ekf.update(np.arange(3, 6), np.eye(3), op[1] - ekf.mean(np.arange(3, 6)), np.eye(3) * 1e-4)
        elif kind == "depth":
            ekf.update(np.array([2]), np.ones((1, 1)), np.array([op[1] - ekf.mean([2])[0]]), np.array([[4e-4]]))
        elif kind == "add":
            G = np.zeros((6, 6))
            G[0:3, 0:3] = np.eye(3)
            ekf.add_landmark(np.r_[ekf.xa[0:3] + [1.0, 0.5, 0.0] + op[1], 0.0, 0.0, 0.0], G,
                             np.diag([0.01, 0.01, 0.01, 1.0, 1.0, 1.0]), label="a", stamp_s=0.0)
        elif kind == "obs":  # z = R^T (l - p) + n
            R = op[2]
            j = next(lm.offset for lm in ekf.landmarks if lm.label == "a")
            idx = np.r_[0:3, j:j + 3]
            H = np.hstack([-R.T, R.T])
            nu = R.T @ ([1.0, 0.5, 0.0]) + op[1] - H @ ekf.mean(idx)
            ekf.update(idx, H, nu, np.eye(3) * 1e-4)
        elif kind == "mark":
            if ekf.recorder is not None:
                ekf.recorder.mark(ekf)
            if clone_at is not None and op[1] == clone_at:
                G = np.zeros((6, 6))
                G[0:3, 0:3] = np.eye(3)
                ekf.add_landmark(np.r_[ekf.xa[0:3], 0.0, 0.0, 0.0], G, np.diag([0.0, 0.0, 0.0, 1.0, 1.0, 1.0]),
                                 label="clone", stamp_s=0.0)
    return ekf


def _new_ekf():
    return SemanticEkf([0.0, 0.0, 2.0], [0.3, 0.0, 0.0], np.diag([1e-4] * 3 + [1e-3] * 3))


@pytest.mark.parametrize("mark", [5, 39, 41, 80, 119])
def test_rts_equals_fixed_point_smoothing_by_augmentation(mark):
    ops = _script()
    ekf = _new_ekf()
    ekf.recorder = RtsRecorder(n_keep=6)
    _run(ops, ekf)
    sm = ekf.recorder.smooth(ekf)
    assert ekf.recorder.status == "ok"
    oracle = _run(ops, _new_ekf(), clone_at=mark)
    clone = next(lm for lm in oracle.landmarks if lm.label == "clone")
    x_clone = oracle.mean(clone.offset + np.arange(3))
    P_clone = oracle.cov(clone.offset + np.arange(3))
    np.testing.assert_allclose(sm.x[mark, 0:3], x_clone, atol=1e-9)
    np.testing.assert_allclose(sm.P[mark, 0:3, 0:3], P_clone, atol=1e-10, rtol=1e-6)
    if mark < 119:  # the data after the mark did inform it
        assert np.trace(sm.P[mark, 0:3, 0:3]) < np.trace(_filtered_cov_at(ops, mark))


def _filtered_cov_at(ops, mark):
    ekf = _new_ekf()
    for i, op in enumerate(ops):
        if op[0] == "mark" and op[1] == mark:
            return _run(ops[:i], ekf).Paa[0:3, 0:3]
    raise AssertionError


def test_recording_leaves_the_filter_unchanged():
    ops = _script(seed=3)
    a = _run(ops, _new_ekf())
    b = _new_ekf()
    b.recorder = RtsRecorder()
    _run(ops, b)
    np.testing.assert_array_equal(a.xa, b.xa)
    np.testing.assert_array_equal(a.Paa, b.Paa)


def test_run_slam_smoothed_trajectory_is_better_and_the_filter_is_unchanged(tmp_path):
    mission = square_dataset(seed=2, loops=2)
    off = run_truth_slam(mission, mode="pose", config=SlamConfig().updated(smooth=False), seed=2)
    on = run_truth_slam(mission, mode="pose", seed=2)
    np.testing.assert_array_equal(off.position_ned_m, on.position_ned_m)
    assert off.smoothed_position_ned_m is None and "smoother" not in off.metrics
    sm = on.metrics["smoother"]
    assert sm["status"] == "ok"
    assert sm["ate_rmse_m"] < on.metrics["ate_rmse_m"]
    # the last epoch has almost no future (a few sensor samples after the last history stamp)
    np.testing.assert_allclose(on.smoothed_position_ned_m[-1], on.position_ned_m[-1], atol=1e-3)
    assert np.all(np.trace(on.smoothed_position_cov_m2, axis1=1, axis2=2)
                  <= np.trace(on.position_cov_m2, axis1=1, axis2=2) + 1e-12)
    out = write_run(on, tmp_path / "run")
    lines = (out / "trajectory_smoothed.csv").read_text().splitlines()
    assert lines[0].startswith("stamp_s,x_m,y_m,z_m") and len(lines) == len(on.stamps_s) + 1
    row = np.array(lines[5].split(","), dtype=float)
    np.testing.assert_allclose(row[1:4], on.smoothed_position_ned_m[4], rtol=1e-8)


def test_smoother_over_budget_is_skipped_and_says_so(tmp_path):
    mission = square_dataset(seed=1, loops=1)
    res = run_truth_slam(mission, mode="pose", config=SlamConfig().updated(smoother_max_mb=0.01), seed=1)
    assert res.metrics["smoother"]["status"].startswith("skipped")
    assert "ate_rmse_m" not in res.metrics["smoother"]
    assert res.smoothed_position_ned_m is None
    out = write_run(res, tmp_path / "run")
    assert not (out / "trajectory_smoothed.csv").exists()


def _smoothed_run(shift, yaw_bias):
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
    sm_wrap, lm_wrap, b_wrap = _smoothed_run(0.0, yaw_bias)
    sm_away, lm_away, b_away = _smoothed_run(np.pi / 2, yaw_bias)
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
    """Catches a changed default budget (512 MB, of which 16 MB in memory) or kept-state count (6: vehicle
    position and velocity)."""
    rec = RtsRecorder()
    assert rec.max_bytes == 512e6 and rec.n_keep == 6 and rec.status == "recording" and rec.active
    assert rec._nodes.ram_bytes == 16e6


@pytest.mark.parametrize("ram_bytes", [0.0, 3e5])
def test_history_in_a_temporary_file_smooths_bit_for_bit_like_in_memory(ram_bytes):
    """The recorder's history all in a temporary file (ram_bytes 0), or half in memory and half on file: the same
    smoothed states to the last bit as all in memory, and the temporary file is gone after the backward pass."""
    ops = _script()
    runs = {}
    for key, budget in (("memory", 1e12), ("file", ram_bytes)):
        ekf = _new_ekf()
        ekf.recorder = RtsRecorder(n_keep=6, ram_bytes=budget)
        _run(ops, ekf)
        store = ekf.recorder._nodes
        assert (store._file is not None) == (key == "file")
        if key == "file" and ram_bytes:
            assert 0 < len(store._mem) < len(store)
        runs[key] = ekf.recorder.smooth(ekf)
        assert ekf.recorder.status == "ok" and store._file is None
    np.testing.assert_array_equal(runs["file"].x, runs["memory"].x)
    np.testing.assert_array_equal(runs["file"].P, runs["memory"].P)
