"""The on-disk cache of derived arrays (semslam._cache) and the cached distance field of the pose search."""

from __future__ import annotations

import numpy as np

from semslam._cache import cached_arrays
from semslam.pose.search import DistanceField


def test_cache_hits_rebuilds_a_corrupt_entry_and_can_be_off(tmp_path, monkeypatch):
    """Catches: a cache that returns stale or corrupt data, or builds again on a hit."""
    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(tmp_path))
    calls = []

    def build():
        calls.append(1)
        return {"a": np.arange(5.0) * len(calls)}

    key = [np.ones(3), "x", 2.5]
    first = cached_arrays("kind", key, build)
    again = cached_arrays("kind", key, build)
    assert len(calls) == 1 and np.array_equal(first["a"], again["a"])
    other = cached_arrays("kind", [np.ones(3), "x", 2.6], build)  # another key: built
    assert len(calls) == 2 and np.array_equal(other["a"], np.arange(5.0) * 2)
    (entry,) = [p for p in (tmp_path / "kind").iterdir() if p.read_bytes() and np.array_equal(
        np.load(p)["a"], np.arange(5.0))]
    entry.write_bytes(b"not a zip")
    rebuilt = cached_arrays("kind", key, build)  # corrupt: rebuilt (with this build's numbers), and rewritten
    assert len(calls) == 3 and np.array_equal(rebuilt["a"], np.arange(5.0) * 3)
    assert not list((tmp_path / "kind").glob(".*.tmp"))
    monkeypatch.setenv("SEMSLAM_NO_CACHE", "1")
    cached_arrays("kind", key, build)
    assert len(calls) == 4


def test_cache_in_an_unwritable_place_still_answers(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(blocker))  # a file: the folder cannot be made
    assert np.array_equal(cached_arrays("k", [1], lambda: {"a": np.zeros(2)})["a"], np.zeros(2))


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
