"""Vectorised kernels of the prerejective RANSAC (batches of hypotheses, no Python loop over points).

Don't call these directly: :func:`semslam.registration.align_prerejective` validates its inputs first.
"""

from __future__ import annotations

import numpy as np


def sample_distinct(rng: np.random.Generator, n_points: int, n_hypotheses: int, n_samples: int) -> np.ndarray:
    """``(n_hypotheses, n_samples)`` sorted, distinct indices in ``[0, n_points)`` (rows with a repeat are redrawn)."""
    out = np.sort(rng.integers(0, n_points, size=(n_hypotheses, n_samples)), axis=1)
    while True:
        bad = np.flatnonzero((np.diff(out, axis=1) == 0).any(axis=1))
        if bad.size == 0:
            return out
        out[bad] = np.sort(rng.integers(0, n_points, size=(bad.size, n_samples)), axis=1)


def polygon_similar(src_xyz: np.ndarray, tgt_xyz: np.ndarray, similarity: float) -> np.ndarray:
    """Holz/Buch polygon pre-rejection, ``(B,)`` bool.

    ``src_xyz`` and ``tgt_xyz`` are ``(B, n, 3)`` polygons. For every edge (i, i+1 mod n) the squared
    length ratio ``min/max`` of the source edge against the target edge must be >= ``similarity**2``.
    """
    ds = np.sum((np.roll(src_xyz, -1, axis=1) - src_xyz) ** 2, axis=2)
    dt = np.sum((np.roll(tgt_xyz, -1, axis=1) - tgt_xyz) ** 2, axis=2)
    lo = np.minimum(ds, dt)
    hi = np.maximum(ds, dt)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(hi > 0, lo / hi, 0.0)
    return (ratio >= similarity * similarity).all(axis=1)


def umeyama_batch(src_xyz: np.ndarray, tgt_xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid transforms (Umeyama 1991, no scaling) of ``(B, n, 3)`` point sets.

    Returns ``R (B, 3, 3)`` and ``t (B, 3)`` with ``tgt ~ src @ R^T + t``.
    """
    mu_s = src_xyz.mean(axis=1)
    mu_t = tgt_xyz.mean(axis=1)
    S = np.einsum("bni,bnj->bij", tgt_xyz - mu_t[:, None], src_xyz - mu_s[:, None])
    U, _, Vt = np.linalg.svd(S)
    d = np.sign(np.linalg.det(U @ Vt))
    d[d == 0] = 1.0
    U[:, :, 2] *= d[:, None]
    R = U @ Vt
    t = mu_t - np.einsum("bij,bj->bi", R, mu_s)
    return R, t


def transforms_from(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Stack ``R (B,3,3)`` and ``t (B,3)`` into ``(B, 4, 4)`` homogeneous matrices."""
    T = np.zeros((len(R), 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = t
    T[:, 3, 3] = 1.0
    return T
