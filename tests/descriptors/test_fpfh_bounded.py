"""FPFH in bounded memory (issue #18, item 4): the radius FPFH streamed from the grid is bit for bit the one
computed from stored neighbourhoods; the neighbour cap (``max_neighbors``, k_max) changes nothing until it is
reached; one far outlier changes no other point's FPFH and does not fall back to the KD-tree. Memory and time
are measured in ``benchmarks/register_budget.py``, not asserted here."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.cli.main import main
from semslam.descriptors.fpfh import compute_fpfh
from semslam.descriptors import estimate_normals, find_neighbors
from semslam.descriptors.neighbors import grid_params
from semslam.errors import InputError


@pytest.fixture(scope="module")
def cloud():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 1, (3000, 3)) * [1, 1, 0.1]
    pts = np.vstack([pts, pts[:50]])  # exact duplicates: pairs at distance 0
    nrm = estimate_normals(pts, radius_m=0.1).normals_xyz
    nrm[::37] = np.nan  # points without a normal
    return pts, nrm


@pytest.mark.parametrize("nan_normals", ["pcl", "skip"])
def test_streamed_radius_fpfh_is_bit_identical_to_stored_neighbourhoods(cloud, nan_normals):
    pts, nrm = cloud
    streamed = compute_fpfh(pts, nrm, radius_m=0.12, nan_normals=nan_normals)
    stored = compute_fpfh(pts, nrm, neighbors=find_neighbors(pts, radius_m=0.12), nan_normals=nan_normals)
    np.testing.assert_array_equal(streamed, stored)


@pytest.mark.parametrize("nan_normals", ["pcl", "skip"])
def test_cap_not_reached_changes_nothing_and_reached_keeps_the_nearest(cloud, nan_normals):
    pts, nrm = cloud
    full = compute_fpfh(pts, nrm, radius_m=0.12, nan_normals=nan_normals)
    most = int(find_neighbors(pts, radius_m=0.12).counts.max())
    np.testing.assert_array_equal(compute_fpfh(pts, nrm, radius_m=0.12, nan_normals=nan_normals,
                                               max_neighbors=most), full)
    capped = compute_fpfh(pts, nrm, radius_m=0.12, nan_normals=nan_normals, max_neighbors=10)
    nb = find_neighbors(pts, radius_m=0.12, max_neighbors=10)
    assert nb.counts.max() == 10 and not nb.symmetric
    np.testing.assert_array_equal(capped, compute_fpfh(pts, nrm, neighbors=nb, nan_normals=nan_normals))
    assert np.isfinite(capped).all() and not np.array_equal(capped, full)
    # the capped neighbourhoods are the nearest ones of the uncapped search
    sorted_full = find_neighbors(pts, radius_m=0.12, sort=True)
    i = int(np.argmax(sorted_full.counts))
    row = sorted_full.sqdist_m2[sorted_full.indptr[i]:sorted_full.indptr[i + 1]]
    np.testing.assert_array_equal(np.sort(nb.sqdist_m2[nb.indptr[i]:nb.indptr[i + 1]]), row[:10])


def test_one_far_outlier_changes_no_other_fpfh(cloud):
    pts, nrm = cloud
    base = compute_fpfh(pts, nrm, radius_m=0.12)
    for outlier in ([1e9, 1e9, 1e9], [-1e9, 0.0, 0.0]):
        q = np.vstack([pts, [outlier]])
        assert grid_params(q, 0.12) is not None  # the grid, sized by occupied cells, not the KD-tree
        f = compute_fpfh(q, np.vstack([nrm, [[0.0, 0.0, 1.0]]]), radius_m=0.12)
        np.testing.assert_allclose(f[:-1], base, rtol=0, atol=1e-9)
        assert not f[-1].any()  # no neighbour: an all-zero row, as PCL


def test_normals_with_a_far_outlier_are_unchanged(cloud):
    pts, _ = cloud
    base = estimate_normals(pts, radius_m=0.1).normals_xyz
    out = estimate_normals(np.vstack([pts, [[1e9, 0.0, 0.0]]]), radius_m=0.1).normals_xyz
    np.testing.assert_allclose(out[:-1], base, rtol=0, atol=1e-9, equal_nan=True)


def test_max_neighbors_is_validated(cloud):
    pts, nrm = cloud
    with pytest.raises(InputError, match="max_neighbors"):
        compute_fpfh(pts, nrm, radius_m=0.1, max_neighbors=0)
    with pytest.raises(InputError, match="max_neighbors"):
        compute_fpfh(pts, nrm, k=10, max_neighbors=5)


def test_describe_fpfh_with_a_far_outlier_and_a_cap(tmp_path, capsys, cloud):
    pts, _ = cloud
    np.save(tmp_path / "c.npy", np.vstack([pts, [[1e9, 1e9, 1e9]]]))
    rc = main(["describe", str(tmp_path / "c.npy"), "--descriptor", "fpfh", "--normal-radius", "0.1",
               "--fpfh-radius", "0.12", "--max-neighbors", "1000", "--point", "5", "--json"])
    import json

    payload = json.loads(capsys.readouterr().out)
    assert rc == 0 and payload["n_bins"] == 33 and payload["max_neighbors"] == 1000
    assert abs(sum(payload["bins"]) - 300.0) < 1e-6
