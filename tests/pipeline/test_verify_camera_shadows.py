"""Verification with the scanner camera's shadows (``PipelineConfig.verify_camera_shadows``): a triangulation laser
returns a point only where its camera also sees the laser's spot, so a right pose of an object that shadows part of
itself from the camera leaves model points the scan cannot have. Oracle: a roof over a floor plate, its camera
shadow cast analytically (as in tests/pose/test_camera_shadow.py); the verification rule against hand-set costs."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from semslam.detection import Detection
from semslam.errors import DatabaseError, InputError
from semslam.geometry import RigidTransform
from semslam.pipeline import PipelineConfig
from semslam.pipeline.hypothesis import camera_visibility, verification_failure
from semslam.pose.model import PoseConfig
from semslam.recognition.database import ViewDatabase
from semslam.symmetry import Symmetry
from tests._support.scenes import ROOF_CAMERA, roof_plates, under_roof

CAMERA = tuple(ROOF_CAMERA)  # scanner frame, from the laser; z forward, down onto the plates
_plates, _under_roof = roof_plates, under_roof


def test_a_right_pose_whose_misses_are_the_camera_shadow_is_explained_only_with_the_camera():
    pts, nrm, n_floor = _plates()
    measured = np.ones(len(pts), dtype=bool)  # what a triangulation scanner returns: neither shadow
    measured[:n_floor] = ~_under_roof(pts[:n_floor], np.zeros(3)) & ~_under_roof(pts[:n_floor], np.array(CAMERA))
    model = SimpleNamespace(visibility_points=pts, visibility_normals=nrm)  # the object frame is the scanner's
    cfg = PoseConfig()
    identity = RigidTransform.identity()
    one_viewpoint = camera_visibility(cfg, pts[measured], np.zeros(3), model, identity, None)
    with_camera = camera_visibility(cfg, pts[measured], np.zeros(3), model, identity, CAMERA)
    assert one_viewpoint > 0.05 and with_camera < 0.02
    # a wrong pose (the object 3 cm nearer the scanner: in front of what it saw) contradicts the scan either way
    nearer = RigidTransform.from_rotation_translation(np.eye(3), [0.0, 0.0, -0.03])
    assert camera_visibility(cfg, pts[measured], np.zeros(3), model, nearer, CAMERA) > 0.5
    assert np.isnan(camera_visibility(cfg, pts[measured], np.zeros(3), SimpleNamespace(
        visibility_points=None, visibility_normals=None), identity, CAMERA))


def _detection(**extras) -> Detection:
    return Detection("a", 0.1, RigidTransform.identity(), np.eye(6) * 1e-4, fitness=1.0, extras=extras)


def test_verification_takes_the_lower_of_the_one_viewpoint_and_camera_costs_of_the_cluster_image():
    assert verification_failure(_detection(pose_visibility=0.3, pose_visibility_camera=0.1), 0.95, 0.15) == ""
    assert "visibility cost 0.300 > 0.15" in verification_failure(_detection(pose_visibility=0.3), 0.95, 0.15)
    # the camera's cost is the higher one: the one viewpoint's is verified
    assert verification_failure(_detection(pose_visibility=0.1, pose_visibility_camera=0.4), 0.95, 0.15) == ""
    assert "0.200 > 0.15" in verification_failure(_detection(pose_visibility=0.3, pose_visibility_camera=0.2),
                                                  0.95, 0.15)
    # a cost against the scene (border-cut clusters) is verified as it is: the camera's is of the cluster image
    failed = verification_failure(_detection(pose_visibility=0.3, pose_visibility_camera=0.1,
                                             pose_visibility_scene=0.25), 0.95, 0.15)
    assert "scene visibility cost 0.250" in failed


def _database(**params) -> ViewDatabase:
    return ViewDatabase(np.array(["a"]), np.array(["v0"]), np.array([0, 3]), np.zeros((3, 3), np.float32),
                        np.zeros((1, 3)), np.ones((1, 640), np.float32), np.ones((1, 308), np.float32),
                        {"a": {"symmetry": Symmetry(), "size_xyz_m": np.ones(3)}}, params)


def test_the_database_gives_its_scanner_camera_and_refuses_a_malformed_one():
    assert _database().scanner_camera_xyz_m is None
    assert _database(scanner_camera_xyz_m=[0.3, 0, 0]).scanner_camera_xyz_m == (0.3, 0.0, 0.0)
    for bad in ([0.3, 0.0], ["x", 0, 0], [float("nan"), 0, 0], "0.3"):
        with pytest.raises(DatabaseError, match="scanner_camera_xyz_m"):
            _ = _database(scanner_camera_xyz_m=bad).scanner_camera_xyz_m


def test_the_setting_is_a_bool_and_on_in_the_seabed_preset_only():
    from semslam.run.config import load_run_config

    with pytest.raises(InputError, match="verify_camera_shadows"):
        PipelineConfig(verify_camera_shadows="yes")
    assert load_run_config(None, preset="seabed").pipeline_config().verify_camera_shadows
    assert not any(load_run_config(None, preset=p).pipeline_config().verify_camera_shadows
                   for p in ("default", "cluttered", "depth-camera"))
