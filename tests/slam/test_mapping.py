"""The object mapper (``semslam/slam/mapping.py``): a new landmark's cross-covariance with the yaw bias, the
record of an ambiguous detection, the active area, the landmark-update gate at its exact limits, the choice of
association algorithm, and what a new or surveyed landmark is initialised with.

The mapper is driven through its public ``process`` on a :class:`SemanticEkf`; a consensus of one observation makes
every unassociated detection a landmark at once, so each scene is built in a few calls. Gate limits are set to the
innovation's own value (computed by the mapper's own function on the same state), so "inside the gate" is tested
at equality."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.detection import Detection
from semslam.geometry import RigidTransform, rotation_from_rpy
from semslam.slam import _ekf_kernels as kern, mapping as mapping_mod
from semslam.slam.association import innovation, measurement_from_detection
from semslam.slam.config import GatingConfig, InitialisationConfig, MapConfig, SlamConfig
from semslam.slam.ekf import SemanticEkf
from semslam.slam.mapping import ObjectMapper
from semslam.symmetry import Symmetry


COV = np.diag([1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3])


def _det(label, t_so, R_so=None, name=""):
    """A detection (score 0.9) of ``label`` at ``t_so`` in the scanner frame, named ``name`` if given; the stamp
    is ``process``'s."""
    R_so = np.eye(3) if R_so is None else R_so
    return Detection(label, 0.9, RigidTransform.from_rotation_translation(R_so, np.asarray(t_so, float)), COV,
                     extras={"object_name": name} if name else {})


def _mapper_on(ekf, **map_cfg):
    """A mapper on ``ekf`` with the map settings ``map_cfg``: (mapper, its update log)."""
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
    mapper, _ = _mapper_on(ekf)
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
    mapper, log = _mapper_on(ekf)
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
    mapper, _ = _mapper_on(ekf, dense_max_landmarks=1, active_radius_m=10.0)
    for label, t in (("a", [3.0, 0.0, 0.0]), ("b", [10.0, 0.0, 0.0]), ("c", [0.0, 30.0, 0.0]), ("d", [0.0, 9.5, 0.0])):
        mapper.process(0.0, [_det(label, t)], np.eye(3), None)
    assert len(ekf.landmarks) == 4
    np.testing.assert_array_equal(ekf.landmark_positions()[1], [10.0, 0.0, 0.0])
    ekf.set_active_landmarks([])
    mapper.process(1.0, [_det("c", [0.0, 30.0, 0.0])], np.eye(3), None)
    assert [ekf.is_active(j) for j in range(4)] == [True, False, True, True]


def _fresh_mapper(association="nn", symmetries=None):
    """A mapper on a bare filter at the origin: (mapper, filter, its update log)."""
    cfg = SlamConfig(initialisation=InitialisationConfig(consensus_min_observations=1),
                     gating=GatingConfig(candidate_radius_m=100.0, association=association))
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-4)
    log = []
    return ObjectMapper(ekf, cfg, "pose", symmetries or {}, RigidTransform.identity(),
                        lambda **kw: log.append(kw)), ekf, log


def _second_look(mapper, ekf):
    """A landmark from one detection, then a second, slightly different detection of it: (x, inn, det)."""
    mapper.process(0.0, [_det("valve", [3.0, 0.0, 0.0])], np.eye(3), None)
    assert len(ekf.landmarks) == 1
    det = _det("valve", [3.01, 0.004, -0.003], rotation_from_rpy(0.01, 0.0, 0.02))
    x = measurement_from_detection(det, RigidTransform.identity(),
                                   unobservable_var_rad2=mapper.cfg.initialisation.unobservable_var_rad2, index=0)
    inn = innovation(ekf, 0, x, np.eye(3), None, orientation_innovation=mapper.cfg.gating.orientation_innovation)
    assert inn.dof_pose > 3 and inn.d2_pose > 0 and inn.d2_position > 0
    return x, inn, det


def test_pose_gate_includes_its_limit():
    """Catches a strict pose gate (``d2 < threshold`` for ``<=``): a detection whose pose NEES equals the chi-square
    limit exactly is inside the gate and updates the landmark with the pose rows."""
    mapper, ekf, log = _fresh_mapper()
    x, inn, det = _second_look(mapper, ekf)
    mapper._thr = dict(mapper._thr)
    mapper._thr[inn.dof_pose] = inn.d2_pose
    log.clear()
    mapper._update_landmark(1.0, x, 0, np.eye(3), None, det)
    (rec,) = log
    assert rec["accepted"] is True and rec["test"] == "pose" and rec["dof"] == inn.dof_pose


def test_position_gate_includes_its_limit_and_uses_three_dof():
    """Catches a strict position gate (``<`` for ``<=``) and a position gate read at the wrong number of degrees of
    freedom (``thr[4]`` for ``thr[3]``): when the pose test fails, a detection whose position NEES equals the
    3-dof limit is accepted with the position rows; one whose NEES lies between the 3-dof and the 4-dof limits is
    rejected, and its record holds the position NEES, 3 dof and the 3-dof limit."""
    mapper, ekf, log = _fresh_mapper()
    x, inn, det = _second_look(mapper, ekf)
    thr = dict(mapper._thr)
    mapper._thr = dict(thr)
    mapper._thr[inn.dof_pose] = 0.5 * inn.d2_pose
    mapper._thr[3] = inn.d2_position
    mapper._thr[4] = 4.0 * inn.d2_position
    log.clear()
    mapper._update_landmark(1.0, x, 0, np.eye(3), None, det)
    (rec,) = log
    assert rec["accepted"] is True and rec["test"] == "position" and rec["dof"] == 3

    mapper, ekf, log = _fresh_mapper()
    x, inn, det = _second_look(mapper, ekf)
    mapper._thr = dict(thr)
    mapper._thr[inn.dof_pose] = 0.5 * inn.d2_pose
    mapper._thr[3] = 0.5 * inn.d2_position
    mapper._thr[4] = 2.0 * inn.d2_position
    log.clear()
    mapper._update_landmark(1.0, x, 0, np.eye(3), None, det)
    (rec,) = log
    assert rec["accepted"] is False and rec["test"] == "none"
    assert rec["dof"] == 3 and rec["threshold"] == mapper._thr[3]
    assert rec["nis"] == pytest.approx(inn.d2_position, rel=1e-12)
    assert ekf.landmarks[0].n_updates == 0


@pytest.mark.parametrize("association", ["nn", "jcbb"])
def test_association_algorithm_follows_the_config(monkeypatch, association):
    """Catches an inverted choice of the association algorithm (``not association == "jcbb"``): with ``nn`` the
    joint-compatibility search is never run; with ``jcbb`` it decides a stamp with several detections of a class."""
    calls = []
    real = mapping_mod.associate_jcbb
    monkeypatch.setattr(mapping_mod, "associate_jcbb", lambda *a, **k: calls.append(a[2]) or real(*a, **k))
    mapper, ekf, _ = _fresh_mapper(association)
    mapper.process(0.0, [_det("valve", [3.0, 0.0, 0.0]), _det("valve", [0.0, 3.0, 0.0])], np.eye(3), None)
    assert len(ekf.landmarks) == 2
    mapper.process(1.0, [_det("valve", [3.01, 0.0, 0.0]), _det("valve", [0.0, 3.01, 0.0])], np.eye(3), None)
    assert calls == ([] if association == "nn" else [2, 2])  # both stamps have two detections of the class
    assert [lm.n_updates for lm in ekf.landmarks] == [1, 1]


def test_surveyed_landmark_is_known_to_the_survey_sigmas():
    """Catches a wrong symmetrisation factor of the surveyed landmarks' covariance (``1.5 (C + C^T)`` for
    ``0.5 (C + C^T)``): a surveyed landmark's position covariance is ``sigma_p^2 I`` and its angles' covariance
    ``sigma_r^2 E^-1 E^-T`` (``E^-1`` the world-rate to rpy-rate map at its attitude)."""
    mapper, ekf, _ = _fresh_mapper()
    rpy = np.array([0.1, -0.2, 0.5])
    T = RigidTransform.from_rotation_translation(rotation_from_rpy(*rpy), [4.0, 1.0, 2.0])
    mapper.add_surveyed(0.0, ["v1"], ["valve"], [T], 0.02, 0.01)
    (lm,) = ekf.landmarks
    _, P = ekf.full_state()
    C = P[lm.offset:lm.offset + 6, lm.offset:lm.offset + 6]
    np.testing.assert_allclose(C[:3, :3], 0.02**2 * np.eye(3), rtol=1e-12, atol=1e-18)
    Einv = kern.world_rate_to_rpy(rpy)
    np.testing.assert_allclose(C[3:, 3:], 0.01**2 * Einv @ Einv.T, rtol=1e-9, atol=1e-18)


def test_new_landmark_of_a_continuous_symmetry_is_free_about_its_axis_and_named():
    """Catches a new landmark that does not get the wide prior (pi^2) on the rotation about an unobservable
    symmetry axis (the loop over the axes skipped), and one that loses the object name its detections carry
    (``if not names``): a pipe detected with its axis along the world z has a world-frame rotation variance >= pi^2
    about z and a small one about x and y; the landmark is named after its detection's ``object_name``."""
    mapper, ekf, _ = _fresh_mapper(symmetries={"pipe": Symmetry("continuous", axis_object=[0.0, 0.0, 1.0])})
    mapper.process(0.0, [_det("pipe", [3.0, 0.0, 0.0], name="pipe_7")], np.eye(3), None)
    (lm,) = ekf.landmarks
    assert lm.name == "pipe_7"
    x, P = ekf.full_state()
    rpy = x[lm.offset + 3:lm.offset + 6]
    E = np.linalg.inv(kern.world_rate_to_rpy(rpy))
    Cw = E @ P[lm.offset + 3:lm.offset + 6, lm.offset + 3:lm.offset + 6] @ E.T
    assert Cw[2, 2] >= np.pi**2
    assert Cw[0, 0] < 0.1 and Cw[1, 1] < 0.1


def test_position_mode_never_updates_with_the_pose_rows():
    """Catches ``or`` for ``and`` in the choice of the pose test (``self.test == "pose" or ...``): a mapper in
    ``position`` mode updates a landmark with its position rows only (3 dof), even for a detection whose full pose
    would pass the pose gate."""
    cfg = SlamConfig(initialisation=InitialisationConfig(consensus_min_observations=1),
                     gating=GatingConfig(candidate_radius_m=100.0))
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-4)
    log = []
    mapper = ObjectMapper(ekf, cfg, "position", {}, RigidTransform.identity(), lambda **kw: log.append(kw))
    x, inn, det = _second_look(mapper, ekf)
    assert inn.d2_pose <= mapper._thr[inn.dof_pose]  # the pose would pass
    log.clear()
    mapper._update_landmark(1.0, x, 0, np.eye(3), None, det)
    (rec,) = log
    assert rec["accepted"] is True and rec["test"] == "position" and rec["dof"] == 3
