"""Tests that kill surviving mutants of ``semslam/slam/mapping.py`` (benchmarks/mutation.py): the landmark-update
gate at its exact limits, the record of a rejected update, the choice of association algorithm, and what a new or
surveyed landmark is initialised with.

The mapper runs on a bare :class:`SemanticEkf` (no sensors); a consensus of one observation makes a detection a
landmark at once. Gate limits are set to the innovation's own value (computed by the mapper's own function on the
same state), so "inside the gate" is tested at equality.
"""

from __future__ import annotations

import numpy as np
import pytest

from semslam.detection import Detection
from semslam.geometry import RigidTransform, rotation_from_rpy
from semslam.slam import _ekf_kernels as kern
from semslam.slam import mapping as mapping_mod
from semslam.slam.association import innovation, measurement_from_detection
from semslam.slam.config import GatingConfig, InitialisationConfig, SlamConfig
from semslam.slam.ekf import SemanticEkf
from semslam.slam.mapping import ObjectMapper
from semslam.symmetry import Symmetry

COV = np.diag([1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3])


def _det(label, t_so, R_so=None, name=""):
    R_so = np.eye(3) if R_so is None else R_so
    return Detection(label, 0.9, RigidTransform.from_rotation_translation(R_so, np.asarray(t_so, float)), COV,
                     extras={"object_name": name} if name else {})


def _mapper(association="nn", symmetries=None):
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
    mapper, ekf, log = _mapper()
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
    mapper, ekf, log = _mapper()
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

    mapper, ekf, log = _mapper()
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
    mapper, ekf, _ = _mapper(association)
    mapper.process(0.0, [_det("valve", [3.0, 0.0, 0.0]), _det("valve", [0.0, 3.0, 0.0])], np.eye(3), None)
    assert len(ekf.landmarks) == 2
    mapper.process(1.0, [_det("valve", [3.01, 0.0, 0.0]), _det("valve", [0.0, 3.01, 0.0])], np.eye(3), None)
    assert calls == ([] if association == "nn" else [2, 2])  # both stamps have two detections of the class
    assert [lm.n_updates for lm in ekf.landmarks] == [1, 1]


def test_surveyed_landmark_is_known_to_the_survey_sigmas():
    """Catches a wrong symmetrisation factor of the surveyed landmarks' covariance (``1.5 (C + C^T)`` for
    ``0.5 (C + C^T)``): a surveyed landmark's position covariance is ``sigma_p^2 I`` and its angles' covariance
    ``sigma_r^2 E^-1 E^-T`` (``E^-1`` the world-rate to rpy-rate map at its attitude)."""
    mapper, ekf, _ = _mapper()
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
    mapper, ekf, _ = _mapper(symmetries={"pipe": Symmetry("continuous", axis_object=[0.0, 0.0, 1.0])})
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
