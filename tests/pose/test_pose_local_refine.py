"""Pose of a large catalogue part whose best grid orientation is ~10 degrees off (issue #15): the gate valve
(RMS radius 11.7 cm, handwheel 14 cm from its centre) seen by the laser as two pieces, body and handwheel, with
the bonnet's top and the stem unseen. The SO(3) grid's hypotheses are ~10 degrees apart; 10 degrees moves the
handwheel by ~2.5 cm, beyond the wide ICP pass (2 cm), and before the local rotation refinement the ICP stopped
at fitness 0.86-0.92, 10-19 degrees off, in these views (as in the catalogue benchmark's scans, where the true
pose fits at 0.99): the union failed verification and the valve was missed."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.cloud import PointCloud
from semslam.errors import InputError
from semslam.pose.estimate import PoseConfig, estimate_object_pose, prepare_pose_model
from semslam.pose.search import _local_rotations, rotation_distances
from semslam.simulation.cad_models import models_view_clouds
from semslam.simulation.catalogue import catalogue_objects
from semslam.simulation.kinect import POSE_MODEL_KINECT
from semslam.simulation.laser_views import laser_view


@pytest.fixture(scope="module")
def gate():
    obj = catalogue_objects()["gate_valve"]
    views, classes = models_view_clouds({"gate_valve": obj}, seed=0, config=POSE_MODEL_KINECT, tied_rests=True)
    return obj, [c for _, _, c in views], classes["gate_valve"]["symmetry"]


# (heading of the laser view in degrees, rotation vector of the object in the scanner frame): views whose grid
# search ended 9.7-18.6 degrees off at fitness 0.86-0.92 without the local refinement (measured, seed = heading)
CASES = [(60, (-2.201254, 0.365753, 0.70931)), (60, (-1.773372, -0.617152, -0.019851)),
         (120, (-0.071451, -0.456485, 2.652323)), (330, (-0.626879, -0.416593, -0.996054))]


def _two_pieces(obj, heading_deg: int):
    cloud, _ = laser_view(obj, np.radians(heading_deg), seed=heading_deg)
    p = cloud.points_xyz_m
    gap = (p[:, 1] > 0.065) & (p[:, 1] < 0.11)  # the bonnet's top and the stem unseen (object frame, y up the stem)
    return p[~gap], cloud.viewpoint_xyz_m


def test_gate_valve_in_two_pieces_gets_its_true_pose(gate):
    obj, views, sym = gate
    model = prepare_pose_model(views)
    assert model.radius_m >= model.config.local_refine_min_radius_m  # the refinement applies to this class
    t = np.array([0.05, -0.1, 1.2])
    for heading, rotvec in CASES:
        p, vp = _two_pieces(obj, heading)
        R = Rotation.from_rotvec(rotvec).as_matrix()
        cloud = PointCloud(p @ R.T + t, viewpoint_xyz_m=R @ vp + t)
        est = estimate_object_pose(cloud, model, symmetry=sym)
        T = est.T_scanner_object.matrix
        err = np.degrees(rotation_distances(R.T, T[None, :3, :3].transpose(0, 2, 1), sym)[0])
        assert err < 4.0, (heading, err, est.fitness)
        assert np.linalg.norm(T[:3, 3] - t) < 0.008, (heading, T[:3, 3] - t)
        assert est.fitness > 0.95 and est.visibility < 0.15, (heading, est.fitness, est.visibility)


def test_local_refinement_settings():
    D = _local_rotations(np.radians(4.0))
    assert D.shape == (27, 3, 3)
    np.testing.assert_allclose(D[0], np.eye(3))
    angles = np.degrees(Rotation.from_matrix(D).magnitude())
    assert angles.max() == pytest.approx(4.0 * np.sqrt(3.0)) and np.sum(np.isclose(angles, 4.0)) == 6
    assert PoseConfig(local_refine_steps_deg=[5, 2.5]).local_refine_steps_deg == (5.0, 2.5)
    assert PoseConfig(local_refine_steps_deg=()).local_refine_steps_deg == ()
    for bad in ((0.0,), (-1.0,), "5", (np.nan,)):
        with pytest.raises(InputError, match="local_refine_steps_deg"):
            PoseConfig(local_refine_steps_deg=bad)
    with pytest.raises(InputError, match="local_refine_min_radius_m"):
        PoseConfig(local_refine_min_radius_m=-0.1)
