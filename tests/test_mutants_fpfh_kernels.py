"""Tests that kill surviving mutants of ``semslam/descriptors/_fpfh_kernels.py`` (benchmarks/mutation.py)."""

from __future__ import annotations

import numpy as np

from semslam.descriptors.fpfh import compute_fpfh


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
