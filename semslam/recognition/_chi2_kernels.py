"""Chi-square distance kernels. Don't call directly: use :class:`semslam.recognition.Chi2NearestNeighbor`.

The distance is FLANN's ``ChiSquareDistance`` as used by PCL's vfh_recognition tutorial::

    d(a, b) = sum_k (a_k - b_k)^2 / (a_k + b_k)     over the bins with a_k + b_k > 0

(no 1/2 factor). It equals ``-sklearn.metrics.pairwise.additive_chi2_kernel(a, b)``.
Inputs are C-contiguous float64 arrays of non-negative values (checked by the callers).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, nogil=True, parallel=True)
def chi2_distance_matrix(X: np.ndarray, Y: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Distances between the rows of ``X`` (n, d) and ``Y`` (m, d): an (n, m) float64 array.

    Parallel over the rows of ``Y`` (the stored views), so that a single query uses every core. With
    non-negative inputs ``a + b == 0`` implies ``a - b == 0``, so dividing by 1 there skips the bin.
    """
    n, d = X.shape
    m = Y.shape[0]
    out = np.empty((n, m))
    for j in prange(m):
        for i in range(n):
            acc = 0.0
            for k in range(d):
                s = X[i, k] + Y[j, k]
                diff = X[i, k] - Y[j, k]
                acc += diff * diff / (s if s > 0.0 else 1.0)
            out[i, j] = acc
    return out


def smallest_k(distances: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` smallest entries of every row of ``distances`` (n, m), sorted ascending.

    Ties are broken by the lower column index (stable), so results do not depend on the platform.
    Returns ``(values (n, k), columns (n, k))``.
    """
    order = np.argsort(distances, axis=1, kind="stable")[:, :k]
    return np.take_along_axis(distances, order, axis=1), order
