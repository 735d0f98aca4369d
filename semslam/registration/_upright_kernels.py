"""Vectorised kernels of :mod:`semslam.registration.upright`: target normals, translation fit with the
rotation held, truncated cost, and the 4-DoF (yaw about a fixed axis + translation) point-to-plane ICP."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

#: neighbours of the target normals' PCA
NORMAL_NEIGHBOURS = 12


def target_normals(pts: np.ndarray, tree: cKDTree) -> np.ndarray:
    """Unit normals (sign arbitrary: point-to-plane does not care) from the PCA of 12 neighbours."""
    k = min(NORMAL_NEIGHBOURS, len(pts))
    _, idx = tree.query(pts, k)
    nb = pts[idx] - pts[idx].mean(axis=1, keepdims=True)
    _, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    return vecs[:, :, 0]


def truncated_cost(src: np.ndarray, tree: cKDTree, R: np.ndarray, t: np.ndarray, mc: float) -> float:
    """Mean over the source of min(d, mc)^2, d the nearest-target distance after ``R p + t``."""
    d = tree.query(src @ R.T + t, distance_upper_bound=mc)[0]
    return float(np.mean(np.minimum(d, mc) ** 2))


def fit_translation(src: np.ndarray, tree: cKDTree, tgt: np.ndarray, R: np.ndarray, t0: np.ndarray, mc: float,
                    iterations: int = 15) -> np.ndarray:
    """Translation of ``R p + t`` by trimmed nearest-neighbour steps from ``t0`` (rotation held).

    The first steps use a 4x wider gate so that a centroid start far from the overlap still moves.
    """
    t = np.asarray(t0, dtype=float).copy()
    rotated = src @ R.T
    for it in range(iterations):
        gate = mc * (4.0 if it < iterations // 3 else 1.0)
        q = rotated + t
        d, i = tree.query(q, distance_upper_bound=gate)
        ok = np.isfinite(d)
        if ok.sum() < 3:
            break
        step = np.mean(tgt[i[ok]] - q[ok], axis=0)
        t += step
        if np.linalg.norm(step) < 1e-3 * mc:
            break
    return t


def point_to_plane_4dof(src: np.ndarray, tree: cKDTree, tgt: np.ndarray, normals: np.ndarray, R: np.ndarray,
                        t: np.ndarray, axis: np.ndarray, mc: float, iterations: int):
    """Gauss-Newton point-to-plane ICP over (yaw about ``axis``, translation); returns R, t, J^T J, iterations.

    Rotation increments are applied on the left about ``axis`` through the target origin:
    ``p' -> exp(dyaw [axis]x) p' + dt``; residual ``n . (p' - q)`` over correspondences within ``mc``.
    """
    R, t = R.copy(), t.copy()
    JtJ = np.eye(4) * 1e-12
    n_it = 0
    for n_it in range(1, iterations + 1):
        q = src @ R.T + t
        d, i = tree.query(q, distance_upper_bound=mc)
        ok = np.isfinite(d)
        if ok.sum() < 4:
            break
        p, qq, n = q[ok], tgt[i[ok]], normals[i[ok]]
        r = np.einsum("ij,ij->i", n, p - qq)
        J = np.empty((len(p), 4))
        J[:, 0] = np.einsum("ij,ij->i", n, np.cross(axis, p))
        J[:, 1:] = n
        JtJ = J.T @ J
        g = J.T @ r
        try:
            delta = -np.linalg.solve(JtJ + 1e-9 * np.eye(4), g)
        except np.linalg.LinAlgError:
            break
        dR = Rotation.from_rotvec(axis * delta[0]).as_matrix()
        R, t = dR @ R, dR @ t + delta[1:]
        if abs(delta[0]) < 1e-6 and np.linalg.norm(delta[1:]) < 1e-6:
            break
    return R, t, JtJ, n_it
