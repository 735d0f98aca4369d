"""A plain cylinder declared ``continuous:z:flip``: its two ends are one pose, not an ambiguity.

Without the flip, the search finds the cylinder's end-for-end twin with the same score and (rightly, for what it
was told) flags the pose as ambiguous with a wide rotation covariance; with it, the twin is the same pose and the
estimate is confident and right."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from semslam.experiments.pose_eval import pose_errors
from semslam.pose import estimate_object_pose, prepare_pose_model
from semslam.pose.covariance import hypothesis_spread
from semslam.pose.search import pairwise_rotation_distances
from semslam.simulation.scan_sim import mesh_model_cloud, scan_mesh
from semslam.slam import _ekf_kernels as kern
from semslam.symmetry import Symmetry

AXIS = Symmetry("continuous", [0.0, 0.0, 1.0])
CYLINDER = Symmetry("continuous", [0.0, 0.0, 1.0], flip=True)


@pytest.fixture(scope="module")
def cylinder():
    mesh = trimesh.creation.cylinder(radius=0.06, height=0.40, sections=64)  # a 0.4 m sonobuoy-like body
    return mesh, prepare_pose_model(mesh_model_cloud(mesh, seed=1))


def _lying_scan(mesh, seed):
    """The cylinder lying on its side 1-1.5 m below the scanner (z down), at a random heading."""
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = (Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)) * Rotation.from_euler("x", np.pi / 2)).as_matrix()
    T[:3, 3] = [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(1.0, 1.5)]
    return T, scan_mesh(mesh, T, n_target_points=2000, range_noise_m=0.001, seed=rng)


def _rotation_covariance(est):
    """The rotation block as a rotation-vector covariance in the scanner frame (from roll pitch yaw rates)."""
    E = kern.rpy_to_world_rate(est.T_scanner_object.as_rpy())
    return E @ est.covariance_6x6[3:, 3:] @ E.T


@pytest.mark.parametrize("seed", [0, 1])
def test_a_cylinder_declared_with_flip_is_posed_confidently_and_right(cylinder, seed):
    mesh, model = cylinder
    T, pts = _lying_scan(mesh, seed)
    est = estimate_object_pose(pts, model, symmetry=CYLINDER, seed=seed)
    rot, trans, nees = pose_errors(est, T, CYLINDER)
    assert np.degrees(rot) < 1.0 and trans < 0.003, (np.degrees(rot), trans)
    assert est.reliable
    R = est.T_scanner_object.rotation
    perpendicular = np.linalg.svd(np.atleast_2d(R @ CYLINDER.axis_object), full_matrices=True)[2][1:]  # scanner frame
    # the tilt of the axis is observed (both perpendicular directions), whichever end the estimate took
    C_rot = _rotation_covariance(est)
    assert np.max(np.linalg.eigvalsh(perpendicular @ C_rot @ perpendicular.T)) < 1e-2
    assert nees < 20.0, nees


def test_without_the_flip_the_other_end_is_an_ambiguity(cylinder):
    mesh, model = cylinder
    T, pts = _lying_scan(mesh, 0)
    est = estimate_object_pose(pts, model, symmetry=AXIS, seed=0)
    C_rot = _rotation_covariance(est)
    assert not est.reliable
    assert sorted(np.linalg.eigvalsh(C_rot))[-2] > 1.0  # a rotation other than the axis's is wide


def test_search_distance_and_spread_treat_the_two_ends_as_one(cylinder):
    rng = np.random.default_rng(3)
    Rs = Rotation.random(10, random_state=4).as_matrix()
    F = CYLINDER.flip_rotation
    # the search's distances are between R^T of T_object_scanner: the object-frame flip acts as F^T R
    flipped = np.einsum("ji,kjl->kil", F, Rs)
    d_flip = pairwise_rotation_distances(Rs, flipped, CYLINDER)
    d_axis = pairwise_rotation_distances(Rs, flipped, AXIS)
    np.testing.assert_allclose(np.diag(d_flip), 0.0, atol=1e-6)
    np.testing.assert_allclose(np.diag(d_axis), np.pi, atol=1e-6)
    T0 = np.eye(4)
    T0[:3, :3], T0[:3, 3] = Rs[0], rng.normal(size=3)
    Tk = T0.copy()
    Tk[:3, :3], Tk[:3, 3] = F.T @ T0[:3, :3], F.T @ T0[:3, 3]  # the same pose seen from the other end
    spread, w = hypothesis_spread(T0, [(0.0, Tk)], CYLINDER, 1.0)
    assert w == pytest.approx(1.0) and np.abs(spread).max() < 1e-6
    spread_axis, _ = hypothesis_spread(T0, [(0.0, Tk)], AXIS, 1.0)
    assert np.abs(spread_axis[3:, 3:]).max() > 1.0
