"""RTS smoother: exact against fixed-point smoothing by state augmentation on a linear run, leaves the filter
unchanged, improves the trajectory of a real run, and says when it is skipped."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.geometry import rotation_from_rpy
from semslam.simulation.truth_slam import run_truth_slam
from semslam.slam.ekf import SemanticEkf
from semslam.slam import SlamConfig
from semslam.run import run_slam
from semslam.run.rundir import write_run
from semslam.slam.smoother import RtsRecorder
from semslam.simulation.synthetic import square_mission


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
    mission = square_mission(seed=2, loops=2)
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
    mission = square_mission(seed=1, loops=1)
    res = run_truth_slam(mission, mode="pose", config=SlamConfig().updated(smoother_max_mb=0.01), seed=1)
    assert res.metrics["smoother"]["status"].startswith("skipped")
    assert "ate_rmse_m" not in res.metrics["smoother"]
    assert res.smoothed_position_ned_m is None
    out = write_run(res, tmp_path / "run")
    assert not (out / "trajectory_smoothed.csv").exists()
