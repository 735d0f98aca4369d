"""Tests that kill surviving mutants of ``semslam/slam/evaluation.py`` (benchmarks/mutation.py).

Oracle: scipy's rotations (angle of ``R_est R_true^T``; angle between the symmetry axes).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.geometry import RigidTransform, rotation_from_rpy
from semslam.slam.evaluation import evaluate_landmark
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
    from semslam.slam.evaluation import evaluate_run
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
