"""Prerejective RANSAC: recovers a known transform from noisy feature matches, reproducibly, with
PCL's polygon pre-rejection and Umeyama estimate checked against analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.errors import InputError, RegistrationError
from semslam.registration import align_prerejective
from semslam.registration import _coarse_kernels as K


def _problem(seed=0, n_target=1500, n_source=700, outlier_share=0.5):
    rng = np.random.default_rng(seed)
    tgt = rng.uniform(-0.2, 0.2, (n_target, 3))
    ft = rng.normal(size=(n_target, 33))
    R = Rotation.from_euler("zyx", [50, 20, -30], degrees=True).as_matrix()
    t = np.array([0.3, -0.1, 0.5])
    idx = rng.choice(n_target, n_source, replace=False)
    src = (tgt[idx] - t) @ R + rng.normal(0, 0.001, (n_source, 3))  # p_target = R p_source + t
    fs = ft[idx] + rng.normal(0, 0.3, (n_source, 33))
    bad = rng.random(n_source) < outlier_share
    fs[bad] = rng.normal(size=(int(bad.sum()), 33))
    return src, fs, tgt, ft, R, t


def test_recovers_known_transform():
    src, fs, tgt, ft, R, t = _problem()
    res = align_prerejective(src, fs, tgt, ft, max_iterations=3000, k_correspondences=2, similarity=0.9,
                             max_correspondence_m=0.005, inlier_fraction=0.25, seed=1)
    assert res.converged
    assert res.fitness > 0.95
    T = res.T_target_source
    assert Rotation.from_matrix(T.rotation.T @ R).magnitude() < np.radians(0.5)
    assert np.linalg.norm(T.translation_m - t) < 0.003
    assert res.inlier_rmse_m < 0.003
    assert res.extras["n_prerejected"] > 0  # the polygon test did reject wrong samples


def test_seeded_and_reproducible():
    src, fs, tgt, ft, *_ = _problem(seed=3)
    kw = dict(max_iterations=500, k_correspondences=3, similarity=0.8, max_correspondence_m=0.005, inlier_fraction=0.1)
    a = align_prerejective(src, fs, tgt, ft, seed=7, **kw)
    b = align_prerejective(src, fs, tgt, ft, seed=7, **kw)
    np.testing.assert_array_equal(a.T_target_source.matrix, b.T_target_source.matrix)
    assert a.fitness == b.fitness


def test_msac_selection_and_early_stop():
    src, fs, tgt, ft, R, t = _problem(seed=4)
    res = align_prerejective(src, fs, tgt, ft, max_iterations=20000, k_correspondences=2, similarity=0.9,
                             max_correspondence_m=0.005, inlier_fraction=0.25, seed=2, selection="msac",
                             stop_fraction=0.9, batch_size=256)
    assert res.converged and res.fitness >= 0.9
    assert res.n_iterations < 20000
    # a 3-point estimate (no refit on the inliers, as PCL): centimetre-level, not millimetre-level
    assert np.linalg.norm(res.T_target_source.translation_m - t) < 0.01
    assert Rotation.from_matrix(res.T_target_source.rotation.T @ R).magnitude() < np.radians(3)


def test_no_consensus_returns_not_converged_with_centroid_guess():
    rng = np.random.default_rng(5)
    src, tgt = rng.uniform(-1, 1, (200, 3)), rng.uniform(-1, 1, (200, 3)) + 5.0
    res = align_prerejective(src, rng.normal(size=(200, 8)), tgt, rng.normal(size=(200, 8)), max_iterations=200,
                             max_correspondence_m=0.001, inlier_fraction=0.9, seed=0, init_T="centroid")
    assert not res.converged
    np.testing.assert_allclose(res.T_target_source.translation_m, tgt.mean(0) - src.mean(0))


def test_umeyama_batch_exact_on_noise_free_points():
    rng = np.random.default_rng(6)
    R = Rotation.random(5, random_state=1).as_matrix()
    t = rng.normal(size=(5, 3))
    src = rng.normal(size=(5, 4, 3))
    tgt = np.einsum("bij,bnj->bni", R, src) + t[:, None]
    R_est, t_est = K.umeyama_batch(src, tgt)
    np.testing.assert_allclose(R_est, R, atol=1e-10)
    np.testing.assert_allclose(t_est, t, atol=1e-10)


def test_polygon_prerejection_matches_definition():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float)
    same = tri @ Rotation.from_euler("z", 40, degrees=True).as_matrix().T + 3.0
    stretched = tri * np.array([1.5, 1.0, 1.0])  # edge 0-1 ratio 1/1.5 = 0.667
    assert K.polygon_similar(tri, same, 0.99)[0]
    assert K.polygon_similar(tri, stretched, 0.6)[0]
    assert not K.polygon_similar(tri, stretched, 0.7)[0]


def test_sample_distinct_rows():
    idx = K.sample_distinct(np.random.default_rng(0), 5, 2000, 3)
    assert idx.shape == (2000, 3)
    assert (np.diff(idx, axis=1) > 0).all() and idx.min() >= 0 and idx.max() < 5


def test_bad_inputs_raise_named_errors():
    src, fs, tgt, ft, *_ = _problem(n_target=50, n_source=20)
    with pytest.raises(InputError, match="target_features"):
        align_prerejective(src, fs[:, :5], tgt, ft)
    with pytest.raises(InputError, match="source_features"):
        align_prerejective(src, fs[:5], tgt, ft)
    with pytest.raises(InputError, match="similarity"):
        align_prerejective(src, fs, tgt, ft, similarity=1.5)
    with pytest.raises(InputError, match="selection"):
        align_prerejective(src, fs, tgt, ft, selection="msac")  # needs a finite distance
    fs_nan = fs.copy()
    fs_nan[2:] = np.nan
    with pytest.raises(RegistrationError, match="finite features"):
        align_prerejective(src, fs_nan, tgt, ft)
