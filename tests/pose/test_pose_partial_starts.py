"""Translation starts of a partial cluster (``PoseConfig.partial_start_step_m``, ``estimate_object_pose(partial=)``):
a flange-like part (a 32 cm ring with a raised hub) seen 20 degrees off its axis and cut by the scan's border so that
only the rim beyond 6 cm of the axis and part of the hub remain: the cluster's centroid lies 10 cm from where the
whole view's would be, beyond the 3 cm the search's translation steps pull in (the shared slip-on flange's border
strips, benchmarks/history/real-models.md)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import InputError
from semslam.pose import PoseConfig, estimate_object_pose, prepare_pose_model
from semslam.pose.search import _partial_offsets
from semslam.simulation.scan_sim import mesh_model_cloud
from semslam.symmetry import Symmetry
from tests._support.scenes import flange_view

AXIS = Symmetry(kind="continuous", axis_object=np.array([0.0, 0.0, 1.0]))


@pytest.fixture(scope="module")
def flange():
    """The part's model cloud, its true T_scanner_object, the cut cluster and the up direction in the scan."""
    mesh, T, pts, in_object = flange_view(20.0)
    cut = pts[in_object[:, 0] > 0.06]
    assert np.linalg.norm(in_object[in_object[:, 0] > 0.06].mean(axis=0)[:2]) > 0.09
    return mesh_model_cloud(mesh, seed=1), T, cut, T[:3, :3] @ [0.0, 0.0, 1.0]


def _estimate(flange, step_m, partial):
    cloud, T, cut, up = flange
    model = prepare_pose_model(cloud, PoseConfig(partial_start_step_m=step_m))
    est = estimate_object_pose(cut, model, symmetry=AXIS, up_scanner=up, up_object=[0.0, 0.0, 1.0], partial=partial)
    Te = est.T_scanner_object.matrix
    return est, float(np.linalg.norm(Te[:3, 3] - T[:3, 3])), AXIS.rotation_error_rad(Te[:3, :3], T[:3, :3])


def test_a_border_cut_rim_is_found_with_the_grid_of_starts_and_not_without(flange):
    est, t_err, r_err = _estimate(flange, 0.04, True)
    assert est.fitness > 0.99 and t_err < 0.003 and np.degrees(r_err) < 1.0
    without, t_without, _ = _estimate(flange, 0.04, False)  # the same model, the cluster taken as whole
    assert t_without > 0.02 and without.fitness < 0.95


def test_the_grid_is_off_by_default_and_for_whole_clusters(flange):
    """Catches the grid run where it was not asked for (a whole cluster whose search ends aligned, or the default
    configuration; an unaligned whole cluster is searched again: test_pose_search_again.py)."""
    a = _estimate(flange, 0.0, True)[0].T_scanner_object.matrix
    b = _estimate(flange, 0.0, False)[0].T_scanner_object.matrix
    c = _estimate(flange, 0.04, False)[0].T_scanner_object.matrix
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(b, c)
    assert PoseConfig().partial_start_step_m == 0.0


def test_no_offsets_without_a_step():
    assert _partial_offsets(np.array([0.0, 0.0, 1.0]), 0.16, 0.0).shape == (0, 3)


def test_bad_settings_are_refused(flange):
    with pytest.raises(InputError, match="partial_start_step_m"):
        PoseConfig(partial_start_step_m=-0.01)
    cloud, _, cut, up = flange
    with pytest.raises(InputError, match="'partial'"):
        estimate_object_pose(cut, prepare_pose_model(cloud), partial="yes")


def test_a_large_part_keeps_the_starts_at_its_resting_height_above_the_floor():
    """A 1.4 m body lying on the floor (up z, its origin 0.18 m above its lowest point), seen from 1.5 m above: of its
    ~2,200 starts only those putting its origin within two grid steps of 0.18 m above the floor are kept, two of the
    grid's eleven layers along the view."""
    from semslam.pose.search import MAX_FREE_STARTS, _resting_starts, resting_height_bands

    rng = np.random.default_rng(0)
    body = rng.uniform([-0.7, -0.18, -0.18], [0.7, 0.18, 0.18], (2000, 3))
    bands = resting_height_bands(body, np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]), 0.04)
    np.testing.assert_allclose(bands, [[0.10, 0.26], [0.10, 0.26]], atol=2e-3)
    view = np.array([0.0, 0.0, 1.0])  # from the cluster up to the scanner (scanner frame: z up here)
    floor = (np.array([0.0, 0.0, 1.0]), 1.5)  # z = -1.5, the scanner on its positive side
    first_origin = np.array([0.1, 0.0, -1.3])  # 0.2 m above the floor
    offsets = _partial_offsets(view, 0.40, 0.04)
    kept = _resting_starts(offsets, first_origin, (floor, bands[:1]))
    np.testing.assert_array_equal(_resting_starts(offsets, first_origin, None), offsets)
    heights = (first_origin - kept) @ floor[0] + floor[1]
    assert len(offsets) > MAX_FREE_STARTS and 0.1 * len(offsets) < len(kept) < 0.3 * len(offsets)
    assert heights.min() >= 0.10 - 1e-9 and heights.max() <= 0.26 + 1e-9
    np.testing.assert_allclose(sorted({round(float(h), 6) for h in heights}), [0.12, 0.2])  # the layers k = 2, 0
    outside = offsets[~np.isin(np.arange(len(offsets)), np.flatnonzero(np.isin(offsets[:, 2], kept[:, 2])))]
    assert np.all(np.abs((first_origin - outside) @ floor[0] + floor[1] - 0.18) > 0.08)


def test_a_bad_floor_is_refused(flange):
    cloud, _, cut, up = flange
    with pytest.raises(InputError, match="'floor_scanner'"):
        estimate_object_pose(cut, prepare_pose_model(cloud), floor_scanner=([0.0, 0.0, 0.0], 1.0))
    with pytest.raises(InputError, match="'floor_scanner'"):
        estimate_object_pose(cut, prepare_pose_model(cloud), floor_scanner=[0.0, 0.0, 1.0])


def test_a_part_under_the_start_budget_is_searched_the_same_with_the_floor(flange):
    """The rim of a 32 cm flange (78 starts) finds the same pose whether the floor is given or not."""
    cloud, T, cut, up = flange
    model = prepare_pose_model(cloud, PoseConfig(partial_start_step_m=0.04))
    kw = dict(symmetry=AXIS, up_scanner=up, up_object=[0.0, 0.0, 1.0], partial=True)
    a = estimate_object_pose(cut, model, **kw).T_scanner_object.matrix
    floor_point = T[:3, 3] - 0.5 * up  # any plane below: the budget is not exceeded, nothing is pruned
    b = estimate_object_pose(cut, model, floor_scanner=(up, -float(up @ floor_point)), **kw).T_scanner_object.matrix
    np.testing.assert_array_equal(a, b)
