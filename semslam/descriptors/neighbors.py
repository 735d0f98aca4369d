"""Fixed-radius and k-nearest neighbourhoods in compressed-row form, shared by normals and FPFH.

One :class:`Neighborhoods` can be computed once (:func:`find_neighbors`) and passed to both
:func:`~semslam.descriptors.estimate_normals` and :func:`~semslam.descriptors.compute_fpfh` when they
use the same search parameter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._validation import as_float_array, check_int, check_positive
from ..errors import DescriptorError, InputError


@dataclass(frozen=True, eq=False)
class Neighborhoods:
    """Neighbour lists of N query points, in compressed-row (CSR) form.

    Attributes
    ----------
    indptr : ndarray of shape (N + 1,), int64
        Neighbours of point ``i`` are ``indices[indptr[i]:indptr[i + 1]]``.
    indices : ndarray of shape (M,), int64
        Point indices. Every list contains the query point itself (at squared distance 0), like PCL's
        searches; k-nearest lists are sorted by increasing distance, radius lists are not.
    sqdist_m2 : ndarray of shape (M,), float64
        Squared distances (m^2) matching ``indices``.
    """

    indptr: np.ndarray
    indices: np.ndarray
    sqdist_m2: np.ndarray

    @property
    def n_points(self) -> int:
        return len(self.indptr) - 1

    @property
    def counts(self) -> np.ndarray:
        """Number of neighbours (query point included) of each point, shape (N,)."""
        return np.diff(self.indptr)

    def check_for(self, n_points: int, caller: str) -> None:
        """Raise InputError unless these neighbourhoods describe ``n_points`` points."""
        if self.n_points != n_points or (self.indices.size and self.indices.max() >= n_points):
            raise InputError(
                f"The 'neighbors' argument of {caller} must describe the {n_points} given points. "
                f"Got neighbourhoods of {self.n_points} points instead."
            )


def find_neighbors(
    points_xyz_m: np.ndarray,
    *,
    k: int | None = None,
    radius_m: float | None = None,
    workers: int = -1,
) -> Neighborhoods:
    """Neighbourhoods of every point, by k nearest neighbours or by radius (exactly one of them).

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points (m), finite.
    k : int, optional
        Number of nearest neighbours, the point itself included (as PCL's ``setKSearch``); clipped to N.
    radius_m : float, optional
        Search radius (m); every point closer than ``radius_m`` (the point itself included) is a
        neighbour, as PCL's ``setRadiusSearch``.
    workers : int
        Threads used by scipy's cKDTree k-nearest query (-1 = all cores); the radius search is
        single-threaded (``cKDTree.sparse_distance_matrix``).

    Returns
    -------
    Neighborhoods
    """
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller="find_neighbors",
                         error=DescriptorError)
    if (k is None) == (radius_m is None):
        raise InputError(
            "Exactly one of the 'k' and 'radius_m' arguments of find_neighbors must be given. "
            f"Got k={k!r} and radius_m={radius_m!r} instead."
        )
    n = len(pts)
    if n == 0:
        return Neighborhoods(np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0))
    tree = cKDTree(pts)
    if k is not None:
        k = min(check_int("k", k, caller="find_neighbors", minimum=1), n)
        dist, idx = tree.query(pts, k=k, workers=workers)
        dist = np.asarray(dist, dtype=np.float64).reshape(n, k)
        idx = np.asarray(idx, dtype=np.int64).reshape(n, k)
        return Neighborhoods(np.arange(n + 1, dtype=np.int64) * k, idx.ravel(), (dist**2).ravel())
    r = check_positive("radius_m", radius_m, caller="find_neighbors")
    # All pairs within r, the point itself included (one vectorised call, with the distances).
    pairs = tree.sparse_distance_matrix(tree, r, output_type="ndarray")
    rows = pairs["i"].astype(np.int64)
    keep = (pairs["v"] < r) | (pairs["j"] == pairs["i"])  # PCL's FLANN radius test is strict
    if not keep.all():
        pairs, rows = pairs[keep], rows[keep]
    if rows.size and not (rows[1:] >= rows[:-1]).all():
        order = np.argsort(rows, kind="stable")
        pairs, rows = pairs[order], rows[order]
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return Neighborhoods(indptr, pairs["j"].astype(np.int64), pairs["v"] ** 2)
