"""VFH against PCL 1.13 (pcl_ref vfh_given / golden files) for every variant."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.descriptors import compute_vfh, estimate_normals
from semslam.errors import DescriptorError


def golden(test_data, name, file="pcl-1.13.txt"):
    for line in (test_data / "descriptors" / file).read_text().splitlines():
        if line.startswith(name + " "):
            return np.array(line.split()[1:], dtype=float)
    raise KeyError(name)


@pytest.fixture(scope="module")
def bun0(test_data):
    d = np.load(test_data / "descriptors" / "bun0.npy").astype(np.float64)
    return d[:, :3], d[:, 3:6]


def assert_bins_equal(ours, ref, rel=1e-4):
    assert ours.shape == (308,)
    np.testing.assert_allclose(ours, ref, rtol=rel, atol=rel * ref.max())


def test_pcl113_bun0_file_normals(test_data, bun0):
    ours = compute_vfh(*bun0)
    assert_bins_equal(ours, golden(test_data, "VFH_bun0_filenormals_default"))
    np.testing.assert_array_equal(ours[135:180], 0.0)  # size component off by default
    used = np.nonzero(ours[180:])[0]
    assert used.min() >= 59 and used.max() <= 70  # the 4-vector view direction squeezes the bins


def test_pcl113_size_and_normalized_distances(test_data, bun0):
    ours = compute_vfh(*bun0, size_component=True, normalize_distances=True)
    assert_bins_equal(ours, golden(test_data, "VFH_bun0_filenormals_size_normdist"))


def test_pcl18_legacy_binning(test_data, bun0):
    ref = golden(test_data, "VFH_bun0_filenormals_legacy_f23", "vfh-bun0-legacy-f23.txt")
    assert_bins_equal(compute_vfh(*bun0, variant="pcl-1.8"), ref)


def test_rusu2010_uses_a_3d_view_direction(bun0):
    ours = compute_vfh(*bun0, variant="rusu2010")
    legacy = compute_vfh(*bun0, variant="pcl-1.8")
    np.testing.assert_array_equal(ours[:180], legacy[:180])
    used = np.nonzero(ours[180:])[0]
    assert used.min() <= 30 and used.max() >= 120  # spread over the 128 bins (25-127 on bun0)
    c = bun0[0].mean(axis=0)
    d = -c / np.linalg.norm(c)
    alpha = np.floor((bun0[1] @ d + 1) / 2 * 128).clip(0, 127).astype(int)
    np.testing.assert_allclose(ours[180:], np.bincount(alpha, minlength=128) * 100 / len(alpha))


def test_pcl113_k10_normals(test_data, bun0):
    normals = estimate_normals(bun0[0], k=10).normals_xyz
    assert_bins_equal(compute_vfh(bun0[0], normals), golden(test_data, "VFH_bun0_k10normals_default"))


@pytest.mark.parametrize("name", ["chef_sub", "bun4_k10", "cylinder"])
def test_pcl113_matches_pcl_ref_vfh_given(test_data, name):
    g = np.load(test_data / "descriptors" / "vfh_pcl.npz")
    cloud = g[f"{name}_cloud"].astype(np.float64)
    assert_bins_equal(compute_vfh(cloud[:, :3], cloud[:, 3:6]), g[f"{name}_vfh"].astype(float))


def test_with_our_normals_close_to_pcl_ref_vfh(test_data):
    # pcl_ref vfh (PCL's own radius normals): our normals differ in the last float32 digits, so a
    # few pairs change bin; the histograms total 400.
    g = np.load(test_data / "descriptors" / "vfh_pcl.npz")
    pts = g["milk3000_points"].astype(np.float64)
    normals = estimate_normals(pts, radius_m=0.01).normals_xyz
    diff = np.abs(compute_vfh(pts, normals) - g["milk3000_vfh_r0.01"])
    assert diff.sum() < 0.5


def test_nan_normals_are_skipped(bun0):
    pts, normals = bun0
    normals = normals.copy()
    normals[::7] = np.nan
    ours = compute_vfh(pts, normals)
    assert np.isfinite(ours).all()
    keep = np.isfinite(normals[:, 0])
    # same as removing those normals, except that the centroid still uses every point
    ref = compute_vfh(pts[keep], normals[keep])
    np.testing.assert_allclose(ours[180:], ref[180:], atol=2.0)
    np.testing.assert_allclose(ours[:180].reshape(4, 45)[:3].sum(axis=1), 100 * keep.sum() / (keep.sum() - 1), rtol=0.02)


def test_bad_input(bun0):
    pts, normals = bun0
    with pytest.raises(DescriptorError, match="at least 2 points"):
        compute_vfh(pts[:1], normals[:1])
    with pytest.raises(DescriptorError, match="normals_xyz"):
        compute_vfh(pts, normals[:-1])
    with pytest.raises(DescriptorError, match="finite normals"):
        compute_vfh(pts[:3], np.full((3, 3), np.nan))
    with pytest.raises(DescriptorError, match="viewpoint"):
        compute_vfh(pts, normals, viewpoint_xyz_m=pts.mean(axis=0), variant="rusu2010")
    with pytest.raises(Exception, match="variant"):
        compute_vfh(pts, normals, variant="pcl-2")
