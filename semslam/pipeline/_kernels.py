"""Numba kernels of the scan-to-detections pipeline (:mod:`semslam.pipeline`). Private: don't call directly."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def selected_input_indices(cluster_voxels, n_voxels, point_voxel):
    """Sorted indices i of the input points whose voxel ``point_voxel[i]`` is one of ``cluster_voxels`` (int64).

    Same result as ``np.flatnonzero(mask[point_voxel])`` with ``mask[cluster_voxels] = True``.
    """
    mask = np.zeros(n_voxels, dtype=np.bool_)
    for v in cluster_voxels:
        mask[v] = True
    count = 0
    for i in range(point_voxel.shape[0]):
        count += mask[point_voxel[i]]
    out = np.empty(count, dtype=np.int64)
    j = 0
    for i in range(point_voxel.shape[0]):
        if mask[point_voxel[i]]:
            out[j] = i
            j += 1
    return out
