"""Evaluation of a SLAM run against truth (``semslam/evaluation/slam_run.py``): orientation errors with and
without symmetry, the landmark metrics, the wrong-object count, the smoothed metrics.

Oracle: scipy's rotations (angle of ``R_est R_true^T``; angle between the symmetry axes)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.evaluation.slam_run import evaluate_landmark
from semslam.geometry import RigidTransform, rotation_from_rpy
from semslam.slam.results import LandmarkEstimate
from semslam.symmetry import Symmetry


def _scene(rpy_est, R_true):
    lm = LandmarkEstimate(0, "tee", np.r_[1.0, 2.0, 3.0, rpy_est], np.eye(6) * 0.01, 0.0, 1.0, 3)
    obj = SimpleNamespace(label="tee", name="tee_1",
                          T_world_object=RigidTransform.from_rotation_translation(R_true, [1.05, 2.0, 3.0]))
    far = SimpleNamespace(label="tee", name="tee_2",
                          T_world_object=RigidTransform.from_rotation_translation(np.eye(3), [9.0, 9.0, 9.0]))
    return lm, [far, obj]


def test_orientation_error_without_symmetry_is_the_rotation_angle():
    """Catches a landmark orientation read from the wrong pose entries (e.g. ``pose[4:6]``) or a symmetry branch
    taken for an asymmetric object: the error is the angle of ``R_est R_true^T`` (scipy), the position error the
    distance to the nearest object of the class."""
    rpy = np.array([0.1, 0.2, 0.3])
    R_true = Rotation.from_rotvec([0.02, -0.05, 0.04]).as_matrix() @ rotation_from_rpy(*rpy)
    lm, objs = _scene(rpy, R_true)
    out = evaluate_landmark(lm, objs, Symmetry())
    assert out.matched_object == "tee_1"
    assert out.position_error_m == pytest.approx(0.05, abs=1e-12)
    assert out.orientation_error_rad == pytest.approx(np.linalg.norm([0.02, -0.05, 0.04]), rel=1e-9)
    assert np.isfinite(out.nees_pose)


def test_orientation_error_of_a_continuous_symmetry_is_the_axis_angle():
    """Catches the continuous-symmetry branch not taken (or taken for every object): for an object symmetric
    about its z axis, a rotation about that axis is no error; the error is the angle between the estimated and
    true axes (here a 0.1 rad tilt), and the pose NEES is undefined (NaN)."""
    rpy = np.array([0.1, 0.2, 0.3])
    R_est = rotation_from_rpy(*rpy)
    R_true = Rotation.from_rotvec([0.1, 0.0, 0.0]).as_matrix() @ R_est @ Rotation.from_rotvec([0, 0, 1.2]).as_matrix()
    lm, objs = _scene(rpy, R_true)
    out = evaluate_landmark(lm, objs, Symmetry("continuous", axis_object=[0.0, 0.0, 1.0]))
    a_est, a_true = R_est[:, 2], R_true[:, 2]
    assert out.orientation_error_rad == pytest.approx(np.arccos(a_est @ a_true), rel=1e-9)
    assert out.orientation_error_rad == pytest.approx(0.1, abs=0.1 * 0.3)
    assert np.isnan(out.nees_pose)


def test_landmark_error_metrics_only_when_there_are_landmarks_and_objects():
    """Catches ``or`` for ``and`` in the landmark-metrics guard: a run with true objects but no landmark mapped (a
    dead-reckoning run) gets no landmark error metrics at all (not keys set to None), and one with both gets them."""
    from semslam.slam import SlamConfig
    from semslam.evaluation.slam_run import evaluate_run
    from semslam.slam.results import SlamResult

    k = 2
    cov = np.tile(np.eye(3), (k, 1, 1))
    res = SlamResult(mode="dr", stamps_s=np.arange(k, dtype=float), position_ned_m=np.zeros((k, 3)),
                     position_cov_m2=cov, velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov,
                     yaw_bias_rad=np.zeros(k), truth_position_ned_m=None, landmarks=[], update_log=[], metrics={},
                     config=SlamConfig())
    lm, objs = _scene(np.array([0.1, 0.2, 0.3]), rotation_from_rpy(0.1, 0.2, 0.3))
    out = evaluate_run(res, SimpleNamespace(truth=None, objects=objs))
    assert not any(key.startswith("landmark_position_error") for key in out.metrics)
    assert "n_objects_mapped" not in out.metrics
    from dataclasses import replace

    out = evaluate_run(replace(res, landmarks=[lm]), SimpleNamespace(truth=None, objects=objs))
    assert out.metrics["n_objects_mapped"] == 1
    assert out.metrics["landmark_position_error_mean_m"] == pytest.approx(0.05, abs=1e-12)


def test_upside_down_axis_of_a_continuous_symmetry_is_pi_not_nan():
    """Catches a cosine clipped to ``[-2, 1]`` instead of ``[-1, 1]`` before ``arccos``: an estimate whose symmetry
    axis is exactly reversed gives a dot product of -1 - 2.2e-16 in floating point, and the orientation error must
    be pi, not NaN."""
    rpy = np.array([0.2739233746429086, -0.4604265724722594, -0.9180529521276106])
    R_true = rotation_from_rpy(*rpy) @ Rotation.from_rotvec([np.pi, 0.0, 0.0]).as_matrix()
    lm, objs = _scene(rpy, R_true)
    axis = np.array([0.0, 0.0, 1.0])
    dot = (rotation_from_rpy(*lm.pose_xyzrpy[3:6]) @ axis) @ (objs[1].T_world_object.rotation @ axis)
    assert dot < -1.0  # the rounding case this test is about
    out = evaluate_landmark(lm, objs, Symmetry("continuous", axis_object=axis))
    assert out.orientation_error_rad == pytest.approx(np.pi, abs=1e-12)

    # a plain cylinder (declared with the flip) upside down is the same cylinder: no error
    flipped = evaluate_landmark(lm, objs, Symmetry("continuous", axis_object=axis, flip=True))
    assert flipped.orientation_error_rad == pytest.approx(0.0, abs=1e-7)


def test_landmark_position_nees_is_the_error_truth_minus_estimate():
    """Catches a position error ``truth + estimate`` (``+`` for ``-``) in the landmark NEES: with the estimate 5 cm
    from the true object along x and covariance 0.01 I, the 3-dof NEES is 0.05^2 / 0.01 = 0.25; the 6-dof NEES of a
    perfect orientation is the same."""
    rpy = np.array([0.1, 0.2, 0.3])
    lm, objs = _scene(rpy, rotation_from_rpy(*rpy))
    out = evaluate_landmark(lm, objs, Symmetry())
    assert out.nees_position == pytest.approx(0.25, rel=1e-9)
    assert out.nees_pose == pytest.approx(0.25, rel=1e-9)


def _result(k=2, landmarks=(), update_log=(), metrics=None, smoothed=None):
    from semslam.slam import SlamConfig
    from semslam.slam.results import SlamResult

    cov = np.tile(np.eye(3), (k, 1, 1))
    return SlamResult(mode="pose", stamps_s=np.arange(k, dtype=float), position_ned_m=np.zeros((k, 3)),
                      position_cov_m2=cov, velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov,
                      yaw_bias_rad=np.zeros(k), truth_position_ned_m=None, landmarks=list(landmarks),
                      update_log=list(update_log), metrics=dict(metrics or {}), config=SlamConfig(),
                      smoothed_position_ned_m=smoothed, smoothed_position_cov_m2=None if smoothed is None else cov)


def test_wrong_object_updates_count_only_accepted_landmark_updates():
    """Catches ``!=`` for ``==`` in the record filter of ``wrong_object_updates``: only *accepted landmark updates*
    whose detection came from another object than the landmark's matched one count -- not a rejected update, not
    the creation of a landmark (``new_landmark``) nor a consensus candidate."""
    from semslam.evaluation.slam_run import evaluate_run

    lm, objs = _scene(np.array([0.1, 0.2, 0.3]), rotation_from_rpy(0.1, 0.2, 0.3))   # matched to tee_1
    log = [dict(kind="landmark", landmark=0, accepted=True, object_name="tee_2"),    # wrong object: counts
           dict(kind="landmark", landmark=0, accepted=True, object_name="tee_1"),    # right object
           dict(kind="landmark", landmark=0, accepted=False, object_name="tee_2"),   # rejected
           dict(kind="new_landmark", landmark=0, accepted=True, object_name="tee_2"),
           dict(kind="candidate", accepted=True, object_name="tee_2")]
    out = evaluate_run(_result(landmarks=[lm], update_log=log), SimpleNamespace(truth=None, objects=objs))
    assert out.metrics["wrong_object_updates"] == 1


@pytest.mark.parametrize("smoother", [False, True])
def test_smoothed_metrics_only_for_a_run_with_a_smoother_and_truth(smoother):
    """Catches ``or`` for ``and`` in the smoothed-metrics guard: a run with ground truth but no smoother (no
    ``metrics["smoother"]``, no smoothed trajectory) gets no smoothed ATE (and no error); a run with both gets the
    smoothed trajectory's ATE against the truth (here 1 m, the online one 0)."""
    from semslam.evaluation.slam_run import evaluate_run

    k = 2
    truth = SimpleNamespace(interpolate_position=lambda t: np.zeros((len(t), 3)))
    res = _result(k, metrics={"smoother": {"status": "ok"}} if smoother else {},
                  smoothed=np.tile([1.0, 0.0, 0.0], (k, 1)) if smoother else None)
    out = evaluate_run(res, SimpleNamespace(truth=truth, objects=[]))
    assert out.metrics["ate_rmse_m"] == 0.0
    if smoother:
        assert out.metrics["smoother"]["status"] == "ok"
        assert out.metrics["smoother"]["ate_rmse_m"] == pytest.approx(1.0, rel=1e-12)
    else:
        assert "smoother" not in out.metrics


def test_landmark_error_summaries_are_nan_aware_and_none_without_any_match():
    """Catches an inverted "any finite error" test of the landmark error summaries (``not np.isfinite(pe).any()``):
    with two landmarks, one matched 5 cm from its object and one of a class with no true object (NaN errors), the
    mean and max position errors are 0.05 m (the NaN ignored) and the orientation error is the matched one's; with
    only the unmatched landmark, every summary is None (not NaN)."""
    from semslam.evaluation.slam_run import evaluate_run

    rpy = np.array([0.1, 0.2, 0.3])
    lm, objs = _scene(rpy, Rotation.from_rotvec([0.0, 0.0, 0.02]).as_matrix() @ rotation_from_rpy(*rpy))
    other = LandmarkEstimate(1, "flange", np.r_[5.0, 5.0, 5.0, rpy], np.eye(6) * 0.01, 0.0, 1.0, 3)
    out = evaluate_run(_result(landmarks=[lm, other]), SimpleNamespace(truth=None, objects=objs))
    m = out.metrics
    assert m["landmark_position_error_mean_m"] == pytest.approx(0.05, abs=1e-12)
    assert m["landmark_position_error_max_m"] == pytest.approx(0.05, abs=1e-12)
    assert m["landmark_orientation_error_mean_deg"] == pytest.approx(np.degrees(0.02), rel=1e-9)
    assert m["n_objects_mapped"] == 1
    m = evaluate_run(_result(landmarks=[other]), SimpleNamespace(truth=None, objects=objs)).metrics
    assert m["landmark_position_error_mean_m"] is None and m["landmark_position_error_max_m"] is None
    assert m["landmark_orientation_error_mean_deg"] is None and m["n_objects_mapped"] == 0
