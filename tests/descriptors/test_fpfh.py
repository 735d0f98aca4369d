"""FPFH against PCL's unit-test values and pcl_ref (PCL 1.13) outputs; a capped run on a two-point
neighbourhood (``_fpfh_kernels.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.descriptors import estimate_normals, find_neighbors
from semslam.descriptors._pair_kernels import fpfh_from_spfh
from semslam.descriptors.fpfh import compute_fpfh, compute_spfh
from semslam.errors import DescriptorError


@pytest.fixture(scope="module")
def bun0(test_data):
    d = np.load(test_data / "descriptors" / "bun0.npy").astype(np.float64)
    return d[:, :3], d[:, 3:6]


def test_spfh_point0_all_neighbours_matches_pcl_unit_test(bun0):
    pts, nrm = bun0
    spfh = compute_spfh(pts, nrm, neighbors=find_neighbors(pts, k=len(pts)))
    f1 = [0.757576, 0.757576, 4.54545, 19.697, 40.6566, 21.4647, 7.57576, 0, 0, 0.50505, 4.0404]
    f2 = [0.757576, 1.51515, 6.31313, 9.59596, 20.7071, 18.9394, 15.9091, 12.8788, 6.56566, 4.29293, 2.52525]
    f3 = [0, 5.05051, 4.54545, 5.05051, 1.76768, 3.0303, 9.09091, 31.8182, 22.2222, 11.8687, 5.55556]
    np.testing.assert_allclose(spfh[0], f1 + f2 + f3, atol=1e-4)


def test_weighting_matches_pcl_unit_test(bun0):
    # weightPointSPFHSignature with indices = all points and squared distances dists[i] = i.
    pts, nrm = bun0
    nb = find_neighbors(pts, k=len(pts))
    spfh = compute_spfh(pts, nrm, neighbors=nb)
    n = len(pts)
    out = fpfh_from_spfh(spfh, np.array([0, n]), np.arange(n), np.arange(n, dtype=float))
    expected = [1.9798, 2.86927, 8.47911, 22.8784, 29.8597, 19.6877, 7.38611, 1.44265, 0.69677, 1.72609,
                2.99435, 2.26313, 5.16573, 8.3263, 9.92427, 16.8062, 16.2767, 12.251, 10.354, 6.65578,
                6.1437, 5.83341, 1.08809, 3.34133, 5.59236, 5.6355, 3.03257, 1.37437, 7.99746, 18.0343,
                23.691, 19.8475, 10.3655]
    np.testing.assert_allclose(out[0], expected, atol=1e-2)


def test_compute_k397_matches_pcl_unit_test(bun0):
    pts, nrm = bun0
    fpfh = compute_fpfh(pts, nrm, k=397)
    expected = [1.58591, 1.68365, 6.71, 23.0717, 33.3844, 20.4002, 7.31067, 1.02635, 0.48591, 1.47069,
                2.87061, 1.78321, 4.30795, 7.05514, 9.37615, 17.963, 18.2801, 14.2766, 10.8542, 6.07925,
                5.28565, 4.73887, 0.56984, 3.29826, 5.28156, 5.26939, 3.13191, 1.74453, 9.41971, 21.5894,
                24.6302, 17.7764, 7.28878]
    np.testing.assert_allclose(fpfh[0], expected, atol=1e-2)
    np.testing.assert_allclose(fpfh.reshape(-1, 3, 11).sum(axis=2), 100.0, rtol=1e-9)


@pytest.mark.parametrize("name", ["bun0", "chef_sub", "milk_sub"])
def test_matches_pcl_ref_fpfh(test_data, name):
    # pcl_ref fpfh CLOUD NORMAL_RADIUS FEATURE_RADIUS, for three points of each cloud.
    g = np.load(test_data / "descriptors" / "fpfh_pcl.npz")
    pts = g[f"{name}_points"].astype(np.float64)
    nr, fr = g[f"{name}_radii"]
    normals = estimate_normals(pts, radius_m=nr).normals_xyz
    fpfh = compute_fpfh(pts, normals, radius_m=fr)
    n_exact = 0
    for first, expected in zip(g[f"{name}_first"], g[f"{name}_fpfh"]):
        # PCL works in float32: a pair on a bin edge (or at the swap test's tie) may change bin,
        # moving ~0.1 of the 300 total; otherwise we agree to float32 precision.
        diff = np.abs(fpfh[first] - expected)
        assert diff.sum() < 0.5
        n_exact += diff.max() < 1e-4
    assert n_exact >= 2


def test_isolated_points_nan_normals_and_duplicates_never_give_nan():
    rng = np.random.default_rng(1)
    pts = np.vstack([rng.random((60, 3)) * 0.1, [[5, 5, 5]], rng.random((1, 3)) * 0.1])
    pts[-1] = pts[0]  # an exact duplicate
    normals = estimate_normals(pts, k=8).normals_xyz
    normals[3] = np.nan
    for mode in ("pcl", "skip"):
        fpfh = compute_fpfh(pts, normals, radius_m=0.05, nan_normals=mode)
        assert np.isfinite(fpfh).all()
        np.testing.assert_array_equal(fpfh[60], 0.0)  # no neighbour: all-zero row, as PCL
        sums = fpfh.reshape(-1, 3, 11).sum(axis=2)
        assert np.allclose(sums[sums > 0], 100.0)
    nb = find_neighbors(pts, radius_m=0.05)
    # PCL: the NaN normal's pairs fall in bins 0 of f1 and f2 (and f3 for the point's own SPFH)
    spfh_pcl = compute_spfh(pts, normals, neighbors=nb)
    incr = 100.0 / (nb.counts[3] - 1)
    np.testing.assert_allclose(spfh_pcl[3, [0, 11, 22]], 100.0)
    has3 = [i for i in range(len(pts)) if i != 3 and 3 in nb.indices[nb.indptr[i]:nb.indptr[i + 1]]]
    assert has3 and all(spfh_pcl[i, 0] >= 100.0 / (nb.counts[i] - 1) - 1e-9 for i in has3)
    assert incr > 0
    # "skip": the NaN-normal point is left out of its neighbours' SPFH
    spfh_nan = compute_spfh(pts, normals, neighbors=nb, nan_normals="skip")
    keep = np.ones(len(pts), bool)
    keep[3] = False
    sub = compute_spfh(pts[keep], normals[keep], neighbors=find_neighbors(pts[keep], radius_m=0.05),
                       nan_normals="skip")
    np.testing.assert_allclose(spfh_nan[keep], sub, atol=1e-12)


def test_bad_input():
    with pytest.raises(DescriptorError, match="normals_xyz"):
        compute_fpfh(np.zeros((5, 3)), np.zeros((4, 3)), radius_m=0.1)
    with pytest.raises(DescriptorError, match="radius_m"):
        compute_fpfh(np.zeros((5, 3)), np.zeros((5, 3)))


def test_capped_run_keeps_the_fpfh_of_a_two_point_neighbourhood():
    """Catches a capped (``max_neighbors``) SPFH that drops neighbourhoods of exactly two points (the point and
    one neighbour: ``k <= 2`` for ``k < 2``): in a cloud where a dense patch reaches the cap, an isolated pair
    (0.05 m apart, 0.12 m radius) is not capped, so its rows must equal the uncapped computation, and be
    non-zero (PCL's SPFH of a pair: one pair feature at weight 100)."""
    rng = np.random.default_rng(0)
    patch = rng.uniform(-0.05, 0.05, size=(60, 3)) * [1.0, 1.0, 0.1]
    pair = np.array([[2.0, 2.0, 0.0], [2.05, 2.0, 0.01]])
    pts = np.vstack([patch, pair])
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    nrm[-1] = [0.1, 0.0, 0.995]
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    full = compute_fpfh(pts, nrm, radius_m=0.12)
    capped = compute_fpfh(pts, nrm, radius_m=0.12, max_neighbors=5)
    assert not np.array_equal(capped[:60], full[:60])          # the cap did bite on the patch
    assert full[-2:].any(axis=1).all()
    np.testing.assert_array_equal(capped[-2:], full[-2:])
