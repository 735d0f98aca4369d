"""Issue #29, item 6: the VFH normal radius from the cloud's own scale when the user does not give it.

The default keeps the simulator's path bit-identical (3 voxels of the default 5 mm grid = the former fixed 15 mm);
views without a fixed grid get a radius from their measured spacing, so the same objects in metres, centimetres
or millimetres get the same VFH and the same recognition, where the former fixed 15 mm failed outside metres.
"""

from __future__ import annotations

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.errors import DescriptorError
from semslam.simulation.synthetic_views import synthetic_shape_views
from semslam.recognition import Recognizer, build_database, compute_view_descriptors
from semslam.recognition.view_descriptors import (AUTO, DEFAULT_NORMAL_RADIUS_M, DEFAULT_VOXEL_LEAF_M,
                                                  NORMAL_EXTENT_FRACTION, default_normal_radius,
                                                  resolve_descriptor_lengths)

N_SAMPLES = 1000


def _scaled(views, k):
    return [(lab, vid, PointCloud(c.points_xyz_m * k, viewpoint_xyz_m=c.viewpoint_xyz_m * k, frame_id=c.frame_id))
            for lab, vid, c in views]


@pytest.fixture(scope="module")
def shapes():
    return synthetic_shape_views(4, n_points=400, seed=2)


def test_default_radius_is_three_voxels_of_a_fixed_grid_else_from_the_spacing():
    assert default_normal_radius(DEFAULT_VOXEL_LEAF_M) == DEFAULT_NORMAL_RADIUS_M == 0.015  # exactly: same path
    assert default_normal_radius(0.002) == pytest.approx(0.006)
    assert default_normal_radius(None) == AUTO and default_normal_radius(AUTO) == AUTO


def test_without_a_grid_the_radius_follows_the_views_size_in_any_unit(shapes):
    clouds = [c for _, _, c in shapes[0]]
    got = resolve_descriptor_lengths(clouds, normal_radius_m=None, voxel_leaf_m=None)
    auto = resolve_descriptor_lengths(clouds, normal_radius_m=AUTO, voxel_leaf_m=None)
    diag = np.median([np.linalg.norm(np.ptp(c.points_xyz_m, axis=0)) for c in clouds])
    assert got["extent_m"] == pytest.approx(diag)
    assert got["normal_radius_m"] == pytest.approx(max(auto["normal_radius_m"], NORMAL_EXTENT_FRACTION * diag))
    assert got["normal_radius_m"] > auto["normal_radius_m"]  # these views are dense for their size
    mm = resolve_descriptor_lengths([c for _, _, c in _scaled(shapes[0], 1000.0)], normal_radius_m=None,
                                    voxel_leaf_m=None)
    assert mm["normal_radius_m"] == pytest.approx(1000.0 * got["normal_radius_m"], rel=1e-6)
    assert mm["vfh_scale"] == pytest.approx(got["vfh_scale"] / 1000.0, rel=1e-6)


def test_default_database_is_bit_identical_to_the_former_fixed_radius(shapes):
    views, classes = shapes
    a = build_database(views[:4], {"sphere": classes["sphere"]}, seed=1, esf_n_samples=N_SAMPLES)
    b = build_database(views[:4], {"sphere": classes["sphere"]}, seed=1, esf_n_samples=N_SAMPLES,
                       normal_radius_m=DEFAULT_NORMAL_RADIUS_M)
    assert a.params["normal_radius_m"] == 0.015 and "vfh_scale" not in a.params
    np.testing.assert_array_equal(a.vfh, b.vfh)
    np.testing.assert_array_equal(a.esf, b.esf)


def test_raw_views_get_the_same_vfh_in_any_unit(shapes):
    views, _ = shapes
    cloud = views[5][2]
    ref = compute_view_descriptors(cloud, esf_n_samples=N_SAMPLES, seed=0).vfh
    for k in (100.0, 1000.0):  # centimetres, millimetres
        got = compute_view_descriptors(_scaled([("x", "v", cloud)], k)[0][2], esf_n_samples=N_SAMPLES, seed=0).vfh
        # float32 rounding may move a feature across a bin edge: at most a few points' worth of mass moves
        assert np.abs(got - ref).sum() < 0.05 * ref.sum(), k
    # the former fixed 15 mm on the same view in millimetres: no normal at all
    mm = _scaled([("x", "v", cloud)], 1000.0)[0][2]
    with pytest.raises(DescriptorError, match="normal_radius_m=0.015"):
        compute_view_descriptors(mm, normal_radius_m=0.015, esf_n_samples=N_SAMPLES)


def test_vfh_recognition_does_not_depend_on_the_unit(shapes):
    """Raw views (no voxel grid) at 4 azimuths, held-out views at 4 others: the VFH nearest view gets the same
    classes in metres and in centimetres with the default radius, as many right as the former fixed 15 mm in metres;
    the fixed 15 mm cannot describe the centimetre views at all (0.15 mm there, below the point spacing)."""
    views, classes = shapes
    held_out, _ = synthetic_shape_views(4, n_points=400, seed=7, phase_rad=np.pi / 4)
    results = {}
    for k in (1.0, 100.0):
        db = build_database(_scaled(views, k), classes, seed=0, voxel_leaf_m=None, esf_n_samples=N_SAMPLES)
        rec = Recognizer(db, descriptor="vfh", rejection="none")
        results[k] = [rec.match(c, seed=0).label for _, _, c in _scaled(held_out, k)]
    truth = np.array([lab for lab, _, _ in held_out])
    assert results[1.0] == results[100.0]
    # no worse than the former fixed 15 mm on the views in metres (their home unit)
    db = build_database(views, classes, seed=0, voxel_leaf_m=None, normal_radius_m=0.015, esf_n_samples=N_SAMPLES)
    rec = Recognizer(db, descriptor="vfh", rejection="none")
    former = np.mean(np.array([rec.match(c, seed=0).label for _, _, c in held_out]) == truth)
    assert np.mean(np.array(results[100.0]) == truth) >= former >= 0.5
    with pytest.raises(DescriptorError):
        build_database(_scaled(views, 100.0), classes, voxel_leaf_m=None, normal_radius_m=0.015,
                       esf_n_samples=N_SAMPLES)
