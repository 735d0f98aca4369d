"""Tests that kill surviving mutants of ``semslam/slam/mapping.py`` (benchmarks/mutation.py).

The mapper is driven through its public ``process``; a consensus of one observation makes every unassociated
detection a landmark at once, so each scene is built in a few calls.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.detection import Detection
from semslam.geometry import RigidTransform, rotation_from_rpy
from semslam.slam.config import GatingConfig, InitialisationConfig, MapConfig, SlamConfig
from semslam.slam.ekf import SemanticEkf
from semslam.slam.mapping import ObjectMapper

COV = np.diag([1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3])


def _det(label, t_so, R_so=None):
    """A detection (score 0.9) of ``label`` at ``t_so`` in the scanner frame; the stamp is ``process``'s."""
    R_so = np.eye(3) if R_so is None else R_so
    return Detection(label, 0.9, RigidTransform.from_rotation_translation(R_so, np.asarray(t_so, float)), COV)


def _mapper(ekf, **map_cfg):
    cfg = SlamConfig(initialisation=InitialisationConfig(consensus_min_observations=1),
                     gating=GatingConfig(candidate_radius_m=100.0), map=MapConfig(**map_cfg))
    log = []
    return ObjectMapper(ekf, cfg, "pose", {}, RigidTransform.identity(), lambda **kw: log.append(kw)), log


def test_new_landmark_cross_covariance_with_the_yaw_bias():
    """Catches a wrong sign (or value) of the new landmark's Jacobian with respect to the AHRS yaw bias: the
    landmark is ``l = p + Rz(-b) R_ahrs t`` (yaw ``yaw_ahrs - b``), so right after initialisation its covariance
    with the bias is ``(dl/db) var(b)`` (dl/db by central differences of scipy rotations) and its yaw's is
    ``-var(b)``."""
    var_b = 0.01
    P0 = np.diag([1e-4] * 6 + [var_b])
    ekf = SemanticEkf(np.array([1.0, -2.0, 3.0]), np.zeros(3), P0, yaw_bias=True)
    b = 0.05
    ekf.xa[ekf.i_yaw] = b
    mapper, _ = _mapper(ekf)
    R_ahrs = rotation_from_rpy(0.1, -0.05, 0.7)
    t = np.array([2.0, 0.5, 1.5])
    mapper.process(0.0, [_det("valve", t)], R_ahrs, None)
    assert len(ekf.landmarks) == 1
    x, P = ekf.full_state()
    off = ekf.landmarks[0].offset

    def l_of(bb):
        return np.array([1.0, -2.0, 3.0]) + Rotation.from_euler("z", -bb).as_matrix() @ R_ahrs @ t

    np.testing.assert_allclose(x[off:off + 3], l_of(b), atol=1e-12)
    h = 1e-6
    dl_db = (l_of(b + h) - l_of(b - h)) / (2 * h)
    np.testing.assert_allclose(P[off:off + 3, ekf.i_yaw], dl_db * var_b, rtol=1e-6, atol=1e-10)
    assert P[off + 5, ekf.i_yaw] == pytest.approx(-var_b, rel=1e-9)


def test_ambiguous_detection_is_logged_as_rejected():
    """Catches an ambiguous detection (gated with a landmark that another detection of the same stamp took)
    logged as accepted: it is dropped, and its record says ``accepted=False``, ``reason="ambiguous"``."""
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-4)
    mapper, log = _mapper(ekf)
    mapper.process(0.0, [_det("valve", [3.0, 0.0, 0.0])], np.eye(3), None)
    assert len(ekf.landmarks) == 1
    log.clear()
    mapper.process(1.0, [_det("valve", [3.0, 0.0, 0.0]), _det("valve", [3.005, 0.0, 0.0])],
                   np.eye(3), None)
    amb = [r for r in log if r.get("reason") == "ambiguous"]
    assert len(amb) == 1 and amb[0]["accepted"] is False
    assert [r["accepted"] for r in log if r["kind"] == "landmark" and "reason" not in r] == [True]
    assert len(ekf.landmarks) == 1


def test_active_area_is_strictly_within_the_radius_plus_the_updated_landmark():
    """Catches a wrong active area of a large map (beyond ``dense_max_landmarks``): before updating a passive
    landmark, the active set becomes the landmarks strictly closer than ``active_radius_m`` to the vehicle (one at
    exactly the radius, 10 m, stays passive) plus the updated one, however far."""
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-4)
    mapper, _ = _mapper(ekf, dense_max_landmarks=1, active_radius_m=10.0)
    for label, t in (("a", [3.0, 0.0, 0.0]), ("b", [10.0, 0.0, 0.0]), ("c", [0.0, 30.0, 0.0]), ("d", [0.0, 9.5, 0.0])):
        mapper.process(0.0, [_det(label, t)], np.eye(3), None)
    assert len(ekf.landmarks) == 4
    np.testing.assert_array_equal(ekf.landmark_positions()[1], [10.0, 0.0, 0.0])
    ekf.set_active_landmarks([])
    mapper.process(1.0, [_det("c", [0.0, 30.0, 0.0])], np.eye(3), None)
    assert [ekf.is_active(j) for j in range(4)] == [True, False, True, True]
