"""Core data model: transforms, point clouds, detections, symmetry declarations, validation messages."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.cloud import PointCloud
from semslam.detection import Detection
from semslam.geometry import RigidTransform
from semslam.errors import InputError, SemslamError
from semslam.geometry import (
    quat_wxyz_from_rotation,
    rotation_from_quat_wxyz,
    rotation_from_rpy,
    rotations_from_rpy,
    rpy_from_rotation,
    wrap_angle,
)
from semslam.symmetry import Symmetry


def test_rpy_matches_scipy_intrinsic_zyx():
    rng = np.random.default_rng(0)
    for roll, pitch, yaw in rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi], size=(50, 3)):
        expected = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
        np.testing.assert_allclose(rotation_from_rpy(roll, pitch, yaw), expected, atol=1e-12)
        np.testing.assert_allclose(rpy_from_rotation(expected), [roll, pitch, yaw], atol=1e-9)


def test_vectorised_rpy_equals_scalar():
    rpy = np.random.default_rng(1).uniform(-3, 3, size=(20, 3))
    batch = rotations_from_rpy(rpy)
    for i in range(20):
        np.testing.assert_allclose(batch[i], rotation_from_rpy(*rpy[i]), atol=1e-14)


def test_gimbal_lock_gives_no_nan_and_same_rotation():
    for pitch in (np.pi / 2, -np.pi / 2):
        R = rotation_from_rpy(0.3, pitch, 1.1)
        rpy = rpy_from_rotation(R)
        assert np.isfinite(rpy).all()
        np.testing.assert_allclose(rotation_from_rpy(*rpy), R, atol=1e-9)


def test_quaternion_round_trip_and_sign():
    R = Rotation.from_rotvec([0.2, -1.0, 2.5]).as_matrix()
    q = quat_wxyz_from_rotation(R)
    assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
    np.testing.assert_allclose(rotation_from_quat_wxyz(q), R, atol=1e-12)
    np.testing.assert_allclose(rotation_from_quat_wxyz(-q), R, atol=1e-12)


def test_wrap_angle_range():
    a = np.array([-7.0, -np.pi, 0.0, np.pi, 7.0])
    w = wrap_angle(a)
    assert (w >= -np.pi).all() and (w < np.pi).all()
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)


def test_transform_compose_inverse_apply():
    T_a_b = RigidTransform.from_xyz_rpy([1, 2, 3], [0.1, -0.2, 0.3])
    T_b_c = RigidTransform.from_quat_wxyz([0.9, 0.1, 0.3, -0.2], [0.5, 0, -1])
    p_c = np.random.default_rng(2).normal(size=(10, 3))
    np.testing.assert_allclose((T_a_b @ T_b_c).apply(p_c), T_a_b.apply(T_b_c.apply(p_c)), atol=1e-12)
    np.testing.assert_allclose((T_a_b @ T_a_b.inverse()).matrix, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(RigidTransform.from_xyz_rpy(*np.split(T_a_b.as_xyz_rpy(), 2)).matrix, T_a_b.matrix, atol=1e-12)


def test_transform_rejects_non_rotation_with_clear_message():
    M = np.eye(4)
    M[0, 0] = 1.01
    with pytest.raises(InputError, match=r"matrix\[:3, :3\].*rotation.*Got max"):
        RigidTransform(M)
    reflection = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(InputError, match="det"):
        RigidTransform(reflection)
    with pytest.raises(InputError, match=r"shape \(4, 4\)"):
        RigidTransform(np.eye(3))
    with pytest.raises(InputError, match="finite"):
        RigidTransform(np.full((4, 4), np.nan))


def test_pointcloud_validation_and_select():
    pts = np.arange(12.0).reshape(4, 3)
    cloud = PointCloud(pts, fields={"rgba": np.arange(4, dtype=np.uint32)})
    assert cloud.n_points == 4 and cloud.points_xyz_m.dtype == np.float64
    assert not cloud.points_xyz_m.flags.writeable
    sub = cloud.select([0, 2])
    np.testing.assert_array_equal(sub.points_xyz_m, pts[[0, 2]])
    np.testing.assert_array_equal(sub.fields["rgba"], [0, 2])
    with pytest.raises(InputError, match=r"'points_xyz_m'.*shape \(N, 3\).*Got \(4, 4\)"):
        PointCloud(np.zeros((4, 4)))
    with pytest.raises(InputError, match="finite"):
        PointCloud(np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(InputError, match="field 'rgba'"):
        PointCloud(pts, fields={"rgba": np.arange(3)})
    with pytest.raises(InputError, match="indices"):
        cloud.select([7])


def test_pointcloud_transformed_moves_viewpoint_and_normals():
    cloud = PointCloud([[1.0, 0, 0]], normals_xyz=[[1.0, 0, 0]], viewpoint_xyz_m=[0, 0, 0])
    T = RigidTransform.from_xyz_rpy([0, 0, 1], [0, 0, np.pi / 2])
    moved = cloud.transformed(T, "world")
    np.testing.assert_allclose(moved.points_xyz_m, [[0, 1, 1]], atol=1e-12)
    np.testing.assert_allclose(moved.normals_xyz, [[0, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(moved.viewpoint_xyz_m, [0, 0, 1], atol=1e-12)
    assert moved.frame_id == "world"


def test_detection_round_trip_and_validation():
    det = Detection("elbow", 0.12, RigidTransform.from_xyz_rpy([1, 0, 2], [0, 0.1, 0.2]), np.eye(6) * 1e-4,
                    fitness=0.9, rmse_m=0.002, n_points=1200, stamp_s=3.5, scan_id=7)
    back = Detection.from_dict(det.to_dict())
    np.testing.assert_allclose(back.T_sensor_object.matrix, det.T_sensor_object.matrix)
    np.testing.assert_allclose(back.covariance_6x6, det.covariance_6x6)
    assert (back.label, back.scan_id, back.n_points) == ("elbow", 7, 1200)
    bad = np.eye(6)
    bad[0, 1] = 1.0
    with pytest.raises(InputError, match="symmetric"):
        Detection("elbow", 0.1, RigidTransform.identity(), bad)
    with pytest.raises(InputError, match="positive semi-definite"):
        Detection("elbow", 0.1, RigidTransform.identity(), -np.eye(6))
    with pytest.raises(InputError, match="label"):
        Detection("", 0.1, RigidTransform.identity(), np.eye(6))


def test_symmetry_declarations():
    assert Symmetry().kind == "none"
    s = Symmetry("continuous", axis_object=[0, 0, 2.0])
    np.testing.assert_allclose(s.axis_object, [0, 0, 1])
    assert Symmetry.from_dict(s.to_dict()).kind == "continuous"
    assert Symmetry("discrete", axis_object=[1, 0, 0], order=2).order == 2
    with pytest.raises(InputError, match="order"):
        Symmetry("discrete", axis_object=[1, 0, 0], order=1)
    with pytest.raises(InputError, match="kind"):
        Symmetry("spherical")
    with pytest.raises(InputError, match="axis_object"):
        Symmetry("continuous")


def test_every_error_is_a_semslam_error():
    from semslam import errors

    classes = [c for c in vars(errors).values() if isinstance(c, type) and issubclass(c, Exception)]
    assert len(classes) > 10
    assert all(issubclass(c, SemslamError) for c in classes)


def test_quaternions_match_scipy_including_half_turns():
    rng = np.random.default_rng(5)
    rots = list(Rotation.random(200, random_state=7).as_matrix())
    rots += [Rotation.from_rotvec(np.pi * a / np.linalg.norm(a)).as_matrix() for a in rng.normal(size=(20, 3))]
    rots += [np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1]), np.eye(3)]
    for R in rots:
        q = quat_wxyz_from_rotation(R)
        x, y, z, w = Rotation.from_matrix(R).as_quat()
        ref = np.array([w, x, y, z])
        assert min(np.abs(q - ref).max(), np.abs(q + ref).max()) < 1e-12
        np.testing.assert_allclose(rotation_from_quat_wxyz(q), R, atol=1e-12)
