"""The SPFH kernels (``semslam/descriptors/_pair_kernels.py``).

Oracle: the documented identity of the two SPFH kernels: on symmetric neighbourhoods (a radius search)
``spfh_symmetric`` is ``spfh`` bit for bit; ``spfh`` (the kNN path) is otherwise only checked against PCL on small
clouds, where no point has fewer than two neighbours."""

from __future__ import annotations

import numpy as np

from semslam.descriptors._pair_kernels import spfh, spfh_symmetric


def _radius_csr(points, r):
    d2 = ((points[:, None, :] - points[None, :, :]) ** 2).sum(-1)
    rows = [np.flatnonzero(d2[i] <= r * r) for i in range(len(points))]   # each row contains the point itself
    indptr = np.concatenate([[0], np.cumsum([len(x) for x in rows])]).astype(np.int64)
    return indptr, np.concatenate(rows).astype(np.int64)


def test_spfh_equals_the_symmetric_kernel_on_radius_neighbourhoods_with_isolated_points():
    """Catches ``break`` for ``continue`` after a point with fewer than two neighbours (every later row left at 0)
    and a wrong f3 bin (``(f3 - 1) / 2`` for ``(f3 + 1) / 2``) in ``spfh``: on a seeded cloud whose first point is
    isolated, ``spfh`` equals ``spfh_symmetric`` row for row, and every non-isolated row sums to 3 x 100."""
    rng = np.random.default_rng(7)
    pts = np.vstack([[[10.0, 10.0, 10.0]], rng.uniform(0.0, 1.0, (40, 3))])
    nrm = rng.normal(size=pts.shape)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    indptr, indices = _radius_csr(pts, 0.35)
    counts = np.diff(indptr)
    assert counts[0] == 1 and (counts[1:] >= 2).sum() > 30
    valid = np.ones(len(pts), dtype=np.bool_)
    a = spfh(pts, nrm, indptr, indices, valid, False)
    b = spfh_symmetric(pts, nrm, indptr, indices, valid, False)
    np.testing.assert_array_equal(a, b)
    assert not a[0].any()
    np.testing.assert_allclose(a[counts >= 2].sum(axis=1), 300.0, rtol=1e-12)
