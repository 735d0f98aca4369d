"""A whole cluster whose pose search ends unaligned is searched again from the grid of starts of a partial cluster
(``PoseConfig.partial_start_step_m``): a whole cluster can miss much of its part too (a hard hat resting tilted, the
lowest 12 cm of it unseen: its seen centroid 4-5 cm from every centroid start, beyond the 3 cm
that the translation steps pull in; DAVE's hard hat, benchmarks/history/real-models.md, session 38). Here a flange
seen 40 degrees off its axis of which only the rim beyond 9 cm of the axis is seen, not touching the border."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.pose import PoseConfig, estimate_object_pose, prepare_pose_model
from semslam.simulation.scan_sim import mesh_model_cloud
from semslam.symmetry import Symmetry
from tests._support.scenes import flange_view

AXIS = Symmetry(kind="continuous", axis_object=np.array([0.0, 0.0, 1.0]))


@pytest.fixture(scope="module")
def rim():
    mesh, T, pts, in_object = flange_view(40.0)
    return mesh_model_cloud(mesh, seed=1), T, pts, in_object


def _estimate(cloud, T, cluster, step_m):
    model = prepare_pose_model(cloud, PoseConfig(partial_start_step_m=step_m))
    est = estimate_object_pose(cluster, model, symmetry=AXIS, up_scanner=T[:3, :3] @ [0.0, 0.0, 1.0],
                               up_object=[0.0, 0.0, 1.0])
    Te = est.T_scanner_object.matrix
    return est, float(np.linalg.norm(Te[:3, 3] - T[:3, 3])), np.degrees(AXIS.rotation_error_rad(Te[:3, :3], T[:3, :3]))


def test_an_unaligned_whole_cluster_is_found_from_the_grid_of_starts(rim):
    cloud, T, pts, in_object = rim
    cluster = pts[in_object[:, 0] > 0.09]
    without, t_without, _ = _estimate(cloud, T, cluster, 0.0)  # no grid: the centroid starts only
    assert without.fitness < PoseConfig().min_fitness and t_without > 0.05
    assert "searched_again" not in without.extras
    est, t_err, r_err = _estimate(cloud, T, cluster, 0.04)
    assert est.extras.get("searched_again") is True
    assert est.fitness > 0.99 and t_err < 0.003 and r_err < 1.0


def test_an_aligned_whole_cluster_is_not_searched_again(rim):
    """Catches the grid searched for every whole cluster (4-10x the search's time): the rim beyond 3 cm ends at a
    fitness above ``min_fitness`` from the centroid starts (0.85, ~3 cm off: the pipeline's verification at 0.95
    rejects it), so it is not searched again and the grid's step changes nothing."""
    cloud, T, pts, in_object = rim
    cluster = pts[in_object[:, 0] > 0.03]
    a, _, _ = _estimate(cloud, T, cluster, 0.0)
    b, _, _ = _estimate(cloud, T, cluster, 0.04)
    assert a.fitness >= PoseConfig().min_fitness and "searched_again" not in b.extras
    np.testing.assert_array_equal(a.T_scanner_object.matrix, b.T_scanner_object.matrix)
