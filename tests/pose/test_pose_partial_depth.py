"""Translation starts of a partial cluster along the view (``PoseConfig.partial_start_step_m``): the lower arc of a
thin ring standing on its rim, seen steeply from above and cut by the scan's border, lies behind the ring's centre,
~10 cm from where the first start puts it (the shared valve panel's front, benchmarks/history/real-models.md). The
margin a start off the first's depth must win by (:data:`semslam.pose.search.PARTIAL_DEPTH_MARGIN`, against the
panel base's strips lifted onto their far face) is measured by benchmarks/real_models.py only: a synthetic flat
ring (12 mm, seen 25-50 degrees off its axis) is posed right without it too."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import semslam.pose.search as search
from semslam.pose import PoseConfig, estimate_object_pose, prepare_pose_model
from semslam.pose.search import _partial_offsets
from semslam.simulation.scan_sim import mesh_model_cloud, scan_mesh
from semslam.symmetry import Symmetry

RING_AXIS = Symmetry(kind="discrete", axis_object=np.array([0.0, 0.0, 1.0]), order=4)


def _scene(mesh, T, keep, seed=3):
    pts = scan_mesh(mesh, T, n_target_points=5000, range_noise_m=0.001, seed=np.random.default_rng(seed))
    in_object = (pts - T[:3, 3]) @ T[:3, :3]
    return mesh_model_cloud(mesh, seed=1), pts[keep(in_object)], in_object[keep(in_object)]


@pytest.fixture(scope="module")
def standing_ring():
    """A 2 cm thick ring (r 7-12 cm, axis z) standing on its rim (object y up), seen 25 degrees off the vertical;
    only its lower arc (object y < -2 cm) is in the cut cluster."""
    import trimesh

    mesh = trimesh.creation.annulus(r_min=0.07, r_max=0.12, height=0.02)
    T = np.eye(4)  # scanner z down the view; object y up = scanner -z tilted
    T[:3, :3] = Rotation.from_euler("x", -(90.0 - 25.0), degrees=True).as_matrix()
    T[:3, 3] = [0.01, 0.02, 1.2]
    model, cut, seen = _scene(mesh, T, lambda p: p[:, 1] < -0.02)
    up = T[:3, :3] @ [0.0, 1.0, 0.0]
    assert seen[:, 1].mean() < -0.06 and up[2] < -0.4  # the seen arc lies well below the centre; the sensor above
    return model, T, cut, up


def _pose(case, symmetry, up_object):
    model_cloud, T, cut, up = case
    model = prepare_pose_model(model_cloud, PoseConfig(partial_start_step_m=0.04))
    est = estimate_object_pose(cut, model, symmetry=symmetry, up_scanner=up, up_object=up_object, partial=True)
    Te = est.T_scanner_object.matrix
    return est, float(np.linalg.norm(Te[:3, 3] - T[:3, 3]))


def test_the_lower_arc_of_a_standing_ring_is_found_with_the_starts_along_the_view(standing_ring, monkeypatch):
    est, t_err = _pose(standing_ring, RING_AXIS, [0.0, 1.0, 0.0])
    assert est.fitness > 0.99 and t_err < 0.004
    across_only = search._partial_offsets

    def disc(view, radius_m, step_m):
        d = across_only(view, radius_m, step_m)
        return d[np.abs(d @ view) < 1e-9]

    monkeypatch.setattr(search, "_partial_offsets", disc)  # the former grid: across the view only
    without, t_without = _pose(standing_ring, RING_AXIS, [0.0, 1.0, 0.0])
    assert t_without > 0.02 and without.fitness < 0.95


def test_the_offsets_fill_the_ball_in_layers_along_the_view_the_layer_across_it_first():
    view = np.array([0.3, -0.2, 0.93])
    view /= np.linalg.norm(view)
    d = _partial_offsets(view, 0.16, 0.04)
    depth = d @ view
    assert np.all(np.diff(np.round(np.abs(depth), 12)) >= 0)  # the layer across the view first, then by depth
    across = d[np.abs(depth) < 1e-12]
    assert len(across) == sum(1 for i in range(-4, 5) for j in range(-4, 5) if 0 < i * i + j * j <= 16)
    assert len(d) == sum(1 for i in range(-4, 5) for j in range(-4, 5) for k in (-4, -2, 0, 2, 4)
                         if 0 < i * i + j * j + k * k <= 16)
    r = np.linalg.norm(d, axis=1)
    assert r.min() == pytest.approx(0.04) and r.max() <= 0.16 + 1e-12
    assert np.allclose(np.unique(np.round(depth, 12)), [-0.16, -0.08, 0.0, 0.08, 0.16])  # layers 2 steps apart
    layer = d[np.abs(depth - 0.08) < 1e-12] - 0.08 * view
    nearest = np.sort(np.linalg.norm(layer[:, None] - layer[None], axis=2), axis=1)[:, 1]
    assert np.allclose(nearest, 0.04) and np.allclose(layer @ view, 0.0)  # each layer a square grid of the step
