"""Numba kernel of normal estimation: population covariance of each neighbourhood. Don't call directly;
use :func:`semslam.descriptors.estimate_normals`."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def neighborhood_covariances(points_xyz_m, indptr, indices):  # pragma: no cover - compiled
    """Population covariance (divided by n) of each CSR neighbourhood, shape (N, 3, 3).

    Computed around the neighbourhood's mean in two passes (no cancellation for far-away clouds).
    """
    n = len(indptr) - 1
    cov = np.zeros((n, 3, 3))
    for i in range(n):
        lo = indptr[i]
        hi = indptr[i + 1]
        m = hi - lo
        if m == 0:
            continue
        cx = 0.0
        cy = 0.0
        cz = 0.0
        for t in range(lo, hi):
            j = indices[t]
            cx += points_xyz_m[j, 0]
            cy += points_xyz_m[j, 1]
            cz += points_xyz_m[j, 2]
        cx /= m
        cy /= m
        cz /= m
        xx = xy = xz = yy = yz = zz = 0.0
        for t in range(lo, hi):
            j = indices[t]
            dx = points_xyz_m[j, 0] - cx
            dy = points_xyz_m[j, 1] - cy
            dz = points_xyz_m[j, 2] - cz
            xx += dx * dx
            xy += dx * dy
            xz += dx * dz
            yy += dy * dy
            yz += dy * dz
            zz += dz * dz
        cov[i, 0, 0] = xx / m
        cov[i, 0, 1] = cov[i, 1, 0] = xy / m
        cov[i, 0, 2] = cov[i, 2, 0] = xz / m
        cov[i, 1, 1] = yy / m
        cov[i, 1, 2] = cov[i, 2, 1] = yz / m
        cov[i, 2, 2] = zz / m
    return cov
