"""Tests that kill surviving mutants of ``semslam/descriptors/_neighbors_kernels.py`` (benchmarks/mutation.py)."""

from __future__ import annotations

import numpy as np

from semslam.descriptors.neighbors import find_neighbors


def test_grid_with_a_far_outlier_and_a_radius_above_one_unit_matches_brute_force():
    """Catches a wrong cell index in the occupied-cell grid used when one far outlier makes the packed grid too
    big (``floor(p * cell)`` for ``floor(p / cell)``: harmless while cells are below one unit, wrong for a cloud
    in millimetres with a 40 mm radius): every radius neighbourhood must equal the brute-force one (squared
    distance < r^2, the point itself included)."""
    rng = np.random.default_rng(2)
    pts = np.vstack([rng.uniform(0.0, 300.0, size=(150, 3)), [[1e12, -1e12, 5e11]]])
    r = 40.0
    nb = find_neighbors(pts, radius_m=r, method="grid")
    d2 = ((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1)
    for i in range(len(pts)):
        got = np.sort(nb.indices[nb.indptr[i]:nb.indptr[i + 1]])
        np.testing.assert_array_equal(got, np.flatnonzero(d2[i] < r * r))
    assert nb.indptr[-1] - nb.indptr[-2] == 1 and nb.indptr[-1] > 2 * len(pts)
