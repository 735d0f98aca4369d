"""The exact chi-square index against the linear scan (brute force): same rows, same distances bit for bit,
same tie rule, on random, tied and real (ESF/VFH) histograms."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.recognition import Chi2NearestNeighbor, chi2_distances
from semslam.recognition import _chi2_kernels
from semslam.recognition._chi2_index import Chi2Index
from semslam.recognition.matching import AUTO_INDEX_AFTER_QUERIES, AUTO_INDEX_MIN_VIEWS


def brute(Q, X, k):
    """The linear scan Chi2NearestNeighbor used before the index (and still uses with algorithm="brute")."""
    return _chi2_kernels.smallest_k(_chi2_kernels.chi2_distance_matrix(Q, X), k)


def assert_same_as_brute(index, Q, X, k):
    d, i = index.knn(np.ascontiguousarray(Q, dtype=float), k)
    bd, bi = brute(np.ascontiguousarray(Q, dtype=float), X, k)
    np.testing.assert_array_equal(i, bi)
    np.testing.assert_array_equal(d, bd)  # bit for bit, not approximately


def clustered(rng, n, d=64, n_bases=12, noise=2000.0, zeros=0.3):
    """Histograms around a few bases (Poisson noise), some bins empty in every row."""
    bases = rng.gamma(1.0, size=(n_bases, d)) * (rng.uniform(size=(n_bases, d)) > zeros)
    bases[:, : d // 8] = 0.0  # bins empty in the whole database
    rows = bases[rng.integers(n_bases, size=n)]
    return rng.poisson(rows * noise) / noise


def test_sqrt_chi2_is_a_metric():
    # the pruning rests on the triangle inequality of rho = sqrt(d) (the triangular discrimination's root)
    rng = np.random.default_rng(0)

    def histograms():
        sparse = rng.gamma(0.3, size=(3000, 8)) * (rng.uniform(size=(3000, 8)) > 0.3)
        return sparse * 10.0 ** rng.uniform(-3, 3, size=(3000, 1))

    def rho(U, V):
        s = U + V
        return np.sqrt(np.where(s > 0, (U - V) ** 2 / np.where(s > 0, s, 1), 0).sum(axis=1))

    A, B, C = histograms(), histograms(), histograms()
    assert (rho(A, C) <= (rho(A, B) + rho(B, C)) * (1 + 1e-12)).all()
    np.testing.assert_allclose(rho(A, B) ** 2, np.diag(chi2_distances(A, B)), rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])  # float32: the lossless float32 copy; else float64
@pytest.mark.parametrize("k", [1, 3, 10])
def test_random_histograms_match_brute_force(dtype, k):
    rng = np.random.default_rng(1)
    X = np.ascontiguousarray(clustered(rng, 700).astype(dtype), dtype=float)
    index = Chi2Index(X)
    assert (index.Xb.dtype == np.float32) == (dtype == np.float32)
    Q = np.vstack([clustered(rng, 60), X[:20], rng.gamma(1.0, size=(10, X.shape[1]))])  # near, stored, far
    assert_same_as_brute(index, Q, X, k)
    assert_same_as_brute(index, Q[:1], X, k)  # the single-query path
    assert index.n_bounded_.max() < len(X)  # and it did prune


def test_duplicates_and_ties_go_to_the_lower_row():
    rng = np.random.default_rng(2)
    base = clustered(rng, 150, d=32)
    X = np.ascontiguousarray(np.vstack([base, base[::-1], base[:40], np.zeros((3, 32))]))  # every row twice or more
    rng.shuffle(X)
    index = Chi2Index(X, n_clusters=20)
    for k in (1, 2, 5, 7):
        assert_same_as_brute(index, X, X, k)  # each row: itself and its copies at distance 0, lower rows first
        assert_same_as_brute(index, clustered(rng, 30, d=32), X, k)
    # exact ties at a positive distance: two rows symmetric about the query
    q = np.full((1, 4), 2.0)
    Y = np.array([[1.0, 2, 2, 2], [3.0, 2, 2, 2], [2.0, 2, 2, 1], [2.0, 3, 2, 2], [9.0, 9, 9, 9]])
    for n_clusters in (1, 2, 5):
        assert_same_as_brute(Chi2Index(Y, n_clusters=n_clusters), q, Y, 4)


@pytest.mark.parametrize("n_clusters", [1, 2, 50, 400])
def test_any_clustering_gives_the_same_answer(n_clusters):
    rng = np.random.default_rng(3)
    X = np.ascontiguousarray(clustered(rng, 400, d=48))
    Q = clustered(rng, 25, d=48)
    for seed in (0, 1):
        assert_same_as_brute(Chi2Index(X, n_clusters=n_clusters, seed=seed), Q, X, 4)


def test_degenerate_databases():
    X = np.zeros((6, 5))
    assert_same_as_brute(Chi2Index(X), np.array([[0, 0, 0, 0, 0.0], [1, 0, 2, 0, 0.0]]), X, 6)  # all tied
    one = np.array([[0.5, 0.0, 0.5]])
    assert_same_as_brute(Chi2Index(one), np.array([[0.0, 1.0, 0.0]]), one, 1)
    rng = np.random.default_rng(4)
    X = np.ascontiguousarray(clustered(rng, 50, d=16))
    assert_same_as_brute(Chi2Index(X), clustered(rng, 5, d=16), X, 50)  # k = every row
    tiny = np.ascontiguousarray(X * 1e-160)  # subnormal terms
    assert_same_as_brute(Chi2Index(tiny), X[:5] * 1e-160, tiny, 3)


def real_descriptors(rng, n_views):
    """ESF and VFH of simulated Kinect views of the four built-in fittings (real descriptors, PCL layout)."""
    from semslam.descriptors import compute_esf, compute_vfh, estimate_normals
    from semslam.simulation import builtin_view_clouds

    views, _ = builtin_view_clouds(seed=0, n_views=n_views)
    esf, vfh = [], []
    for i, (_, _, cloud) in enumerate(views):
        pts = cloud.points_xyz_m[:: max(1, len(cloud.points_xyz_m) // 1500)]
        esf.append(compute_esf(pts, n_samples=4000, seed=i))
        normals = estimate_normals(pts, radius_m=0.015, viewpoint_xyz_m=cloud.viewpoint_xyz_m).normals_xyz
        vfh.append(compute_vfh(pts, normals, viewpoint_xyz_m=cloud.viewpoint_xyz_m))
    return np.array(esf, np.float32), np.array(vfh, np.float32)


@pytest.fixture(scope="module")
def real():
    return real_descriptors(np.random.default_rng(5), 6)


@pytest.mark.parametrize("which", [0, 1], ids=["esf", "vfh"])
def test_real_descriptors_match_brute_force(real, which):
    # views perturbed like new scans of the same objects (Poisson resampling of each histogram)
    rng = np.random.default_rng(6)
    base = real[which].astype(float)
    total = base.sum(axis=1, keepdims=True)

    def resample(rows, n):
        return (rng.poisson(rows / total[: len(rows)] * n) * total[: len(rows)] / n).astype(np.float32)

    X = np.ascontiguousarray(np.vstack([base, *(resample(base, 3000) for _ in range(40))]), dtype=float)
    Q = np.ascontiguousarray(np.vstack([resample(base, 3000), base]), dtype=float)
    index = Chi2Index(X)
    assert index.Xb.dtype == np.float32
    for k in (1, 5):
        assert_same_as_brute(index, Q, X, k)
    clf = Chi2NearestNeighbor(algorithm="index").fit(X, np.arange(len(X)) % 4)
    np.testing.assert_array_equal(clf.kneighbors(Q, 3)[1], brute(Q, X, 3)[1])


def test_classifier_algorithms_agree():
    rng = np.random.default_rng(7)
    X = clustered(rng, 300, d=40)
    y = np.array(list("abcd"))[rng.integers(4, size=300)]
    Q = clustered(rng, 40, d=40)
    fits = {a: Chi2NearestNeighbor(n_neighbors=3, algorithm=a).fit(X, y) for a in ("brute", "index", "auto")}
    assert fits["brute"].index_ is None and fits["index"].index_ is not None and fits["auto"].index_ is None
    ref = fits["brute"].kneighbors(Q)
    for clf in fits.values():
        d, i = clf.kneighbors(Q)
        np.testing.assert_array_equal(d, ref[0])
        np.testing.assert_array_equal(i, ref[1])
        np.testing.assert_array_equal(clf.predict(Q), fits["brute"].predict(Q))
    assert fits["auto"].index_ is not None  # 40 queries in one call: built at once
    assert fits["brute"].index_ is None


def test_auto_builds_the_index_after_a_few_queries():
    rng = np.random.default_rng(8)
    X = clustered(rng, AUTO_INDEX_MIN_VIEWS, d=24)
    y = np.arange(len(X)) % 3
    Q = clustered(rng, AUTO_INDEX_AFTER_QUERIES, d=24)
    auto = Chi2NearestNeighbor(algorithm="auto").fit(X, y)
    for n, q in enumerate(Q[:-1]):  # one at a time, as a recogniser does
        np.testing.assert_array_equal(auto.kneighbors(q[None])[1], brute(q[None], X, 1)[1])
        assert auto.index_ is None
    auto.kneighbors(Q[-1:])
    assert auto.index_ is not None
    small = Chi2NearestNeighbor().fit(X[:-1], y[:-1])
    small.kneighbors(Q)
    assert small.index_ is None  # fewer than AUTO_INDEX_MIN_VIEWS views: always the linear scan


def test_bad_algorithm():
    from semslam.errors import InputError

    with pytest.raises(InputError, match="algorithm"):
        Chi2NearestNeighbor(algorithm="kd_tree").fit([[1.0]], ["a"])
