"""PCL-compatible point-to-point ICP (SVD/Umeyama steps, PCL's stopping rules), for reproducing PCL.

Don't call this directly: :func:`semslam.registration.align_icp` with ``method="pcl"`` validates first.
small_gicp (Gauss-Newton) converges to the same minimum but stops elsewhere than PCL, whose
criteria (section 4 of ``design/pcl-algorithms.md``) end the loop on an incremental transform with
``cos(angle) >= 1 - eps`` and ``|t|^2 <= eps``, or on ``|dMSE| < 1e-12``, or at the iteration cap.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ._coarse_kernels import umeyama_batch


def icp_pcl(src: np.ndarray, tree: cKDTree, T0: np.ndarray, max_corr: float, max_iterations: int,
            transformation_epsilon: float, euclidean_fitness_epsilon: float = -np.inf,
            mse_threshold_absolute: float = 1e-12, min_correspondences: int = 3,
            ) -> tuple[np.ndarray, int, bool]:
    """Run PCL's ``IterativeClosestPoint`` loop; returns ``(T_target_source, n_iterations, converged)``."""
    tgt = tree.data
    T = np.array(T0, dtype=np.float64)
    moved = src @ T[:3, :3].T + T[:3, 3]
    rot_threshold = 1.0 - transformation_epsilon
    prev_mse = np.finfo(np.float64).max
    n_similar_needed = 0
    for it in range(1, max_iterations + 1):
        d, j = tree.query(moved, k=1, distance_upper_bound=max_corr)
        ok = d * d <= max_corr * max_corr
        if np.count_nonzero(ok) < min_correspondences:
            return T, it - 1, False
        R, t = umeyama_batch(moved[ok][None], tgt[j[ok]][None])
        R, t = R[0], t[0]
        moved = moved @ R.T + t
        D = np.eye(4)
        D[:3, :3], D[:3, 3] = R, t
        T = D @ T
        if it >= max_iterations:
            return T, it, True
        cos_angle = 0.5 * (np.trace(R) - 1.0)
        if cos_angle >= rot_threshold and t @ t <= transformation_epsilon and n_similar_needed == 0:
            return T, it, True
        mse = float(np.mean(d[ok] ** 2))
        if abs(mse - prev_mse) < mse_threshold_absolute:
            return T, it, True
        if abs(mse - prev_mse) / prev_mse < euclidean_fitness_epsilon:
            return T, it, True
        prev_mse = mse
    return T, max_iterations, True
