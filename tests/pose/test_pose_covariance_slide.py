"""The slide profile of the pose covariance: a direction the points can slide along is as uncertain as the slide.

The point-to-plane Hessian alone gave a lying tube cut at one end (a sonobuoy at the scan border) a millimetre of
axial uncertainty when it was posed 75 mm off: a few noisy model normals "saw" the axis. The slide profile
(:func:`semslam.pose.covariance.slide_profile_covariance`) shifts the aligned points along each principal direction
and keeps the interval over which they stay on the model."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from semslam.pose import estimate_object_pose, prepare_pose_model
from semslam.pose.covariance import slide_profile_covariance
from semslam.simulation.scan_sim import mesh_model_cloud, scan_mesh
from semslam.symmetry import Symmetry

TAU = 0.006


def _grid(x0, x1, y0, y1, spacing):
    x, y = np.meshgrid(np.arange(x0, x1 + 1e-9, spacing), np.arange(y0, y1 + 1e-9, spacing))
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def _distances(model_points):
    tree = cKDTree(model_points)
    return lambda q: tree.query(q, distance_upper_bound=TAU)[0]


@pytest.mark.parametrize("x0, expected_a, expected_b", [(0.3, -0.3, 0.5), (0.0, 0.0, 0.8)])
def test_a_patch_on_a_longer_plate_gets_the_second_moment_of_its_free_slide(x0, expected_a, expected_b):
    # the model: a 1 m x 0.2 m plate; the points: a 0.2 m stretch of it across its whole width
    model = _grid(0.0, 1.0, 0.0, 0.2, 0.002)
    pts = _grid(x0, x0 + 0.2, 0.0, 0.2, 0.004)
    C = slide_profile_covariance(pts, _distances(model), np.eye(3), tau_m=TAU, step_m=0.002, max_shift_m=1.0)
    a, b = expected_a, expected_b
    expected = (a * a + a * b + b * b) / 3.0  # uniform on [a, b], second moment about 0
    assert C[0, 0] == pytest.approx(expected, rel=0.05)
    # across the plate (y) the points cover it all, and off the plate (z) every point is lost at once
    assert C[1, 1] < 0.002 ** 2 and C[2, 2] < 1e-12
    assert abs(C[0, 1]) < 1e-12 and abs(C[0, 2]) < 1e-12


def test_an_estimate_at_the_end_of_its_valley_is_less_certain_than_one_in_the_middle():
    model = _grid(0.0, 1.0, 0.0, 0.2, 0.002)
    middle = slide_profile_covariance(_grid(0.4, 0.6, 0.0, 0.2, 0.004), _distances(model), np.eye(3)[:1],
                                      tau_m=TAU, step_m=0.002, max_shift_m=1.0)
    end = slide_profile_covariance(_grid(0.8, 1.0, 0.0, 0.2, 0.004), _distances(model), np.eye(3)[:1],
                                   tau_m=TAU, step_m=0.002, max_shift_m=1.0)
    assert end[0, 0] == pytest.approx(0.8 ** 2 / 3.0, rel=0.05)
    assert middle[0, 0] == pytest.approx(0.4 ** 2 / 3.0, rel=0.05)


TUBE = Symmetry("continuous", [0.0, 0.0, 1.0], flip=True)


@pytest.fixture(scope="module")
def tube():
    mesh = trimesh.creation.cylinder(radius=0.06, height=0.60, sections=64)
    return mesh, prepare_pose_model(mesh_model_cloud(mesh, seed=1))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_lying_tube_cut_at_one_end_is_honestly_uncertain_along_its_axis(tube, seed):
    mesh, model = tube
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = (Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)) * Rotation.from_euler("x", np.pi / 2)).as_matrix()
    T[:3, 3] = [rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(1.0, 1.4)]
    pts = scan_mesh(mesh, T, n_target_points=3000, range_noise_m=0.001, seed=rng)
    axis = T[:3, :3] @ [0.0, 0.0, 1.0]
    s = (pts - T[:3, 3]) @ axis
    for cut, keep in (("whole", np.ones(len(pts), bool)), ("one end", s > -0.15)):
        est = estimate_object_pose(pts[keep], model, symmetry=TUBE, seed=seed, partial=True)
        sd_axial = float(np.sqrt(axis @ est.covariance_6x6[:3, :3] @ axis))
        error_axial = float((est.T_scanner_object.translation_m - T[:3, 3]) @ axis)
        if cut == "whole":  # both ends seen: the axial position is pinned
            assert abs(error_axial) < 0.006 and sd_axial < 0.005, (error_axial, sd_axial)
        else:  # 0.45 m of 0.6 m seen, nothing tells which end is cut: about 0.15 m of free slide
            assert 0.02 < sd_axial < 0.12, sd_axial
            assert abs(error_axial) < 3.0 * sd_axial, (error_axial, sd_axial)
