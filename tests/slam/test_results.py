"""SLAM result records (``semslam/slam/results.py``): position errors with and without truth, immutability."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.slam import SlamConfig
from semslam.slam.results import SlamResult


def test_position_error_is_none_without_truth_and_the_distance_with_it():
    """Catches an inverted "has truth" test in ``SlamResult.position_error_m``: None without ground truth, else the
    per-epoch Euclidean distance to it (a 3-4-0 triangle: 5 m; a difference, not a sum)."""
    k = 2
    cov = np.tile(np.eye(3), (k, 1, 1))
    kw = dict(mode="dr", stamps_s=np.arange(k, dtype=float), position_ned_m=np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 1.0]]),
              position_cov_m2=cov, velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov, yaw_bias_rad=np.zeros(k),
              landmarks=[], update_log=[], metrics={}, config=SlamConfig())
    assert SlamResult(truth_position_ned_m=None, **kw).position_error_m is None
    truth = np.array([[1.0, 1.0, 1.0], [0.0, 0.0, 3.0]])
    kw["position_ned_m"] = kw["position_ned_m"] + truth
    err = SlamResult(truth_position_ned_m=truth, **kw).position_error_m
    np.testing.assert_allclose(err, [5.0, 1.0], rtol=1e-15)


def test_result_records_are_immutable_and_compared_by_identity():
    """Catches result records that became mutable (``frozen=False``) or value-compared (``eq=True``: their arrays
    make ``==`` ambiguous and the objects unhashable; each of ``SlamResult``, ``SlamEstimate`` and
``LandmarkEstimate``): a finished result must not change under its reader."""
    import dataclasses

    from semslam.slam.results import LandmarkEstimate, SlamEstimate

    k = 1
    cov = np.tile(np.eye(3), (k, 1, 1))
    res = SlamResult(mode="dr", stamps_s=np.zeros(k), position_ned_m=np.zeros((k, 3)), position_cov_m2=cov,
                     velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov, yaw_bias_rad=np.zeros(k),
                     truth_position_ned_m=None, landmarks=[], update_log=[], metrics={}, config=SlamConfig())
    lm = LandmarkEstimate(0, "valve", np.zeros(6), np.eye(6), 0.0, 1.0, 2)
    est = SlamEstimate(0.0, np.zeros(3), np.eye(3), np.zeros(3), np.eye(3), 0.0, [])
    for obj, name in ((res, "mode"), (lm, "label"), (est, "stamp_s")):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(obj, name, getattr(obj, name))
    for obj in (res, est, lm):
        twin = dataclasses.replace(obj)
        assert obj != twin and obj == obj and len({obj, twin}) == 2
