"""The on-disk cache of derived arrays (semslam._cache) and the cached distance field of the pose search."""

from __future__ import annotations

import numpy as np
import pytest

from semslam._cache import cached_arrays
from semslam.errors import InputError
from semslam.pose.search import DistanceField


def test_cache_hits_rebuilds_a_corrupt_entry_and_can_be_off(tmp_path, monkeypatch):
    """Catches: a cache that returns stale or corrupt data, or builds again on a hit."""
    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(tmp_path))
    calls = []

    def build():
        calls.append(1)
        return {"a": np.arange(5.0) * len(calls)}

    key = [np.ones(3), "x", 2.5]
    first = cached_arrays("kind_v1", key, build)
    again = cached_arrays("kind_v1", key, build)
    assert len(calls) == 1 and np.array_equal(first["a"], again["a"])
    other = cached_arrays("kind_v1", [np.ones(3), "x", 2.6], build)  # another key: built
    assert len(calls) == 2 and np.array_equal(other["a"], np.arange(5.0) * 2)
    (entry,) = [p for p in (tmp_path / "kind_v1").iterdir() if p.read_bytes() and np.array_equal(
        np.load(p)["a"], np.arange(5.0))]
    entry.write_bytes(b"not a zip")
    rebuilt = cached_arrays("kind_v1", key, build)  # corrupt: rebuilt (with this build's numbers), and rewritten
    assert len(calls) == 3 and np.array_equal(rebuilt["a"], np.arange(5.0) * 3)
    assert not list((tmp_path / "kind_v1").glob(".*.tmp"))
    monkeypatch.setenv("SEMSLAM_NO_CACHE", "1")
    cached_arrays("kind_v1", key, build)
    assert len(calls) == 4


def test_cache_keeps_within_its_limit_by_evicting_the_least_recently_used(tmp_path, monkeypatch):
    """Catches: a cache that grows without bound on a vehicle's disk (every new database adds ~0.3 GB), that evicts
    an entry just read rather than an old one, or that deletes files it did not write."""
    import os

    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(tmp_path))
    (tmp_path / "ros1-bridge").mkdir()
    foreign = tmp_path / "ros1-bridge" / "other.npz"  # not a cache kind: never deleted
    foreign.write_bytes(b"x" * 50_000)
    (tmp_path / "kind_v1").mkdir()
    users = tmp_path / "kind_v1" / "results.npz"  # in a kind's folder but not named by a hash: never deleted
    users.write_bytes(b"y" * 50_000)
    size = 10_000  # bytes of one entry's array: the limit holds two entries, not three

    def entry(i):
        return cached_arrays("kind_v1", [i], lambda: {"a": np.full(size // 8, float(i))})

    monkeypatch.setenv("SEMSLAM_CACHE_MAX_MB", str(2.5 * size / 2**20))
    entry(0)
    entry(1)
    files = sorted(p for p in (tmp_path / "kind_v1").glob("*.npz") if p != users)
    for age, p in enumerate(files):  # both written long ago, in a known order
        os.utime(p, (1e9 + age, 1e9 + age))
    first = min(files, key=lambda p: p.stat().st_mtime)
    assert np.load(first)["a"][0] in (0.0, 1.0)
    read_back = entry(int(np.load(first)["a"][0]))  # used now: the other one is the least recently used
    entry(2)
    left = sorted(float(np.load(p)["a"][0]) for p in (tmp_path / "kind_v1").glob("*.npz") if p != users)
    assert left == sorted({float(read_back["a"][0]), 2.0})
    assert foreign.exists() and users.exists()
    import semslam._cache as cache_module

    monkeypatch.setattr(cache_module, "_warned", [])
    monkeypatch.setenv("SEMSLAM_CACHE_MAX_MB", str(1.5 * size / 2**20))  # one entry: this run's own are evicted
    with pytest.warns(cache_module.CacheLimitWarning, match="Raise SEMSLAM_CACHE_MAX_MB"):
        entry(4)
    monkeypatch.setenv("SEMSLAM_CACHE_MAX_MB", "lots")
    with pytest.raises(InputError, match="SEMSLAM_CACHE_MAX_MB"):
        entry(3)


def test_cache_in_an_unwritable_place_still_answers(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(blocker))  # a file: the folder cannot be made
    assert np.array_equal(cached_arrays("k_v1", [1], lambda: {"a": np.zeros(2)})["a"], np.zeros(2))


def test_cached_distance_field_equals_the_built_one(tmp_path, monkeypatch):
    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(tmp_path))
    pts = np.random.default_rng(0).normal(scale=0.03, size=(500, 3))
    ref = DistanceField.build(pts, cell_m=0.004)
    for _ in range(2):  # built and stored, then read back
        f = DistanceField.build_cached(pts, cell_m=0.004)
        assert np.array_equal(f.offsets, ref.offsets) and np.array_equal(f.index, ref.index)
        assert np.array_equal(f.params, ref.params) and f.truncation_m == ref.truncation_m
    assert len(list((tmp_path / "distance_field_v1").glob("*.npz"))) == 1


def test_cached_view_centroids_equal_the_built_ones(tmp_path, monkeypatch):
    """The translation starts read from the cache are the built ones, NaN (no facing sample) included."""
    from semslam.pose.search import ViewCentroids

    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(tmp_path))
    rng = np.random.default_rng(1)
    nrm = rng.normal(size=(400, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    pts = 0.05 * nrm
    nrm[:] = [0.0, 0.0, 1.0]  # every normal up: the downward directions see nothing (NaN centroids)
    ref = ViewCentroids.build(pts, nrm, n_directions=64)
    assert np.isnan(ref.centroids).any()
    for _ in range(2):
        v = ViewCentroids.build_cached(pts, nrm, n_directions=64)
        assert np.array_equal(v.directions, ref.directions)
        assert np.array_equal(v.centroids, ref.centroids, equal_nan=True)
    assert len(list((tmp_path / "view_centroids_v1").glob("*.npz"))) == 1


def test_cached_rejection_calibration_equals_the_computed_one_and_is_read_back(tmp_path, monkeypatch):
    """Catches: a cold start that computes the database's leave-one-out distances again (~0.5 s on 832 views), or
    a cached entry that gives other thresholds than the computation (same key, other database)."""
    import semslam.recognition.rejection as rejection

    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(tmp_path))
    rng = np.random.default_rng(2)
    X = rng.random((40, 30))
    y = np.repeat(["a", "b", "c", "d"], 10)
    V = rng.normal(size=(40, 3))
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    plain = rejection.loo_same_class_distances(X, y, rejection.same_viewpoint_pairs(V, 10.0))
    ref = float(np.quantile(plain[np.isfinite(plain)], 0.95))
    first = rejection.calibrate_rejection(X, y, view_directions=V)
    calls = []
    monkeypatch.setattr(rejection, "loo_same_class_distances", lambda *a: calls.append(a) or plain)
    again = rejection.calibrate_rejection(X, y, view_directions=V)
    assert not calls, "the second calibration of the same database computed the distances again"
    assert first.global_threshold == again.global_threshold == ref
    other = rejection.calibrate_rejection(X[::-1], y, view_directions=V)  # another database: computed
    assert len(calls) == 1 and np.isfinite(other.global_threshold)


def test_cached_pose_model_samples_and_icp_normals_equal_the_computed_ones(tmp_path, monkeypatch):
    """Catches: a pose model prepared from the cache that differs from one prepared afresh (the normals small_gicp
    estimates, the oriented samples of the search and the visibility), and small_gicp's cloud not built when an
    ICP needs it after its normals came from the cache."""
    import small_gicp

    from semslam.cloud import PointCloud
    from semslam.pose import PoseConfig
    from semslam.pose.model import prepare_pose_model
    from semslam.registration import align_icp, prepare_icp_target

    rng = np.random.default_rng(3)
    d = rng.normal(size=(3000, 3))
    pts = 0.05 * d / np.linalg.norm(d, axis=1, keepdims=True)
    views = [PointCloud(pts[pts @ v > -0.01], viewpoint_xyz_m=0.5 * np.asarray(v, dtype=float))
             for v in ([1.0, 0, 0], [0, 1.0, 0])]
    monkeypatch.setenv("SEMSLAM_NO_CACHE", "1")
    fresh = prepare_pose_model(views, PoseConfig())
    monkeypatch.delenv("SEMSLAM_NO_CACHE")
    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(tmp_path))
    for _ in range(2):  # computed and stored, then read back
        m = prepare_pose_model(views, PoseConfig())
        for name in ("coarse_points", "normals_object", "visibility_points", "visibility_normals"):
            assert np.array_equal(getattr(m, name), getattr(fresh, name)), name
    assert {p.name for p in tmp_path.iterdir()} >= {"icp_normals_v1", "oriented_samples_v1"}
    moved = [PointCloud(v.points_xyz_m + [0.0, 0.0, 0.001], viewpoint_xyz_m=v.viewpoint_xyz_m) for v in views]
    other = prepare_pose_model(moved, PoseConfig())  # another model: its own samples, not the cached ones
    monkeypatch.setenv("SEMSLAM_NO_CACHE", "1")
    other_fresh = prepare_pose_model(moved, PoseConfig())
    monkeypatch.delenv("SEMSLAM_NO_CACHE")
    assert not np.array_equal(other_fresh.coarse_points, fresh.coarse_points)
    for name in ("coarse_points", "normals_object", "visibility_points", "visibility_normals"):
        assert np.array_equal(getattr(other, name), getattr(other_fresh, name)), name
    target = prepare_icp_target(pts, method="plane")  # normals from the cache: small_gicp's parts not built yet
    cloud = small_gicp.PointCloud(pts)
    small_gicp.estimate_normals(cloud, num_neighbors=20)
    assert np.array_equal(target.normals_xyz, cloud.normals()[:, :3])
    shifted = pts[::3] + [0.004, -0.003, 0.002]
    res = align_icp(shifted, target, max_correspondence_m=0.02)
    assert np.allclose(res.T_target_source.matrix[:3, 3], [-0.004, 0.003, -0.002], atol=1e-3)
