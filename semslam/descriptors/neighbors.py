"""Fixed-radius and k-nearest neighbourhoods in compressed-row form, shared by normals and FPFH.

One :class:`Neighborhoods` can be computed once (:func:`find_neighbors`) and passed to both
:func:`~semslam.descriptors.estimate_normals` and :func:`~semslam.descriptors.fpfh.compute_fpfh` when they
use the same search parameter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._validation import as_float_array, check_choice, check_int, check_positive
from ..errors import DescriptorError, InputError
from ._neighbors_kernels import grid_bucket_count, grid_fill, sort_rows


@dataclass(frozen=True, eq=False)
class Neighborhoods:
    """Neighbour lists of N query points, in compressed-row (CSR) form.

    Attributes
    ----------
    indptr : ndarray of shape (N + 1,), int64
        Neighbours of point ``i`` are ``indices[indptr[i]:indptr[i + 1]]``.
    indices : ndarray of shape (M,), int64
        Point indices. Every list contains the query point itself (at squared distance 0), like PCL's
        searches; k-nearest lists are sorted by increasing distance, radius lists are not (unless
        ``find_neighbors(..., sort=True)``).
    sqdist_m2 : ndarray of shape (M,), float64
        Squared distances (m^2) matching ``indices``.
    symmetric : bool
        True when j is a neighbour of i exactly when i is a neighbour of j, with the same squared
        distance (the grid radius search guarantees it); lets FPFH compute each pair once.
    """

    indptr: np.ndarray
    indices: np.ndarray
    sqdist_m2: np.ndarray
    symmetric: bool = False

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
    method: str = "auto",
    sort: bool = False,
    max_neighbors: int | None = None,
) -> Neighborhoods:
    """Neighbourhoods of every point, by k nearest neighbours or by radius (exactly one of them).

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points (m), finite.
    k : int, optional
        Number of nearest neighbours, the point itself included (as PCL's ``setKSearch``); clipped to N.
    radius_m : float, optional
        Search radius (m); every point closer than ``radius_m`` (squared distance < radius^2; the
        point itself included) is a neighbour, as PCL's ``setRadiusSearch``.
    workers : int
        Threads used by scipy's cKDTree k-nearest query (-1 = all cores). The radius search is
        single-threaded.
    method : {"auto", "grid", "kdtree"}
        Radius search: "grid" a uniform grid of cells of side ~``radius_m`` (numba, fastest);
        "kdtree" scipy's ``cKDTree.sparse_distance_matrix``; "auto" the grid unless the cloud
        spans more than 2^52 radii along an axis. The grid is sized by its occupied cells (its
        memory follows the points, not the extent), so one far outlier costs nothing. The
        neighbour sets are the same (up to points at exactly ``radius_m``, where the two round
        differently); their order within a row differs. k-nearest searches always use cKDTree.
    sort : bool
        Sort every radius neighbourhood by increasing distance (then index); k-nearest lists are
        always sorted.
    max_neighbors : int, optional
        Radius search (grid) only: keep at most this many neighbours per point (the point itself
        included), the nearest ones, like FLANN's ``max_nn``. Bounds the memory (16 bytes per kept
        pair) and time on very dense clouds; neighbourhoods below the cap are exactly the uncapped
        ones. Capped neighbourhoods are not symmetric. None (default): no cap, as PCL.

    Returns
    -------
    Neighborhoods
    """
    caller = "find_neighbors"
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller, error=DescriptorError)
    if (k is None) == (radius_m is None):
        raise InputError(
            "Exactly one of the 'k' and 'radius_m' arguments of find_neighbors must be given. "
            f"Got k={k!r} and radius_m={radius_m!r} instead."
        )
    check_choice("method", method, ("auto", "grid", "kdtree"), caller=caller)
    n = len(pts)
    if n == 0:
        return Neighborhoods(np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if k is not None:
        k = min(check_int("k", k, caller=caller, minimum=1), n)
        dist, idx = cKDTree(pts).query(pts, k=k, workers=workers)
        dist = np.asarray(dist, dtype=np.float64).reshape(n, k)
        idx = np.asarray(idx, dtype=np.int64).reshape(n, k)
        return Neighborhoods(np.arange(n + 1, dtype=np.int64) * k, idx.ravel(), (dist**2).ravel())
    r = check_positive("radius_m", radius_m, caller=caller)
    cap = 0 if max_neighbors is None else check_int("max_neighbors", max_neighbors, caller=caller, minimum=1)
    grid = grid_params(pts, r)
    if method == "kdtree" or (method == "auto" and grid is None):
        if cap:
            raise InputError(f"The 'max_neighbors' argument of {caller} needs the grid search. Got method="
                             f"{method!r} on a cloud the grid cannot take (extent {np.ptp(pts, axis=0).max()} m).")
        nb = _kdtree_radius(pts, r)
    elif grid is None:
        raise DescriptorError(
            f"The 'points_xyz_m' argument of {caller} (method='grid') must span fewer than "
            f"{_MAX_CELLS_PER_AXIS} radii along every axis. Got an extent of "
            f"{float(np.ptp(pts, axis=0).max())} m for radius_m={r}; use method='kdtree'."
        )
    else:
        nb = _grid_radius(pts, grid[0], r, grid[1], cap)
    if sort:
        sort_rows(nb.indptr, nb.indices, nb.sqdist_m2)
    return nb


#: The grid search handles clouds spanning fewer cells than this along every axis; the grid is sized by its
#: occupied cells, not by the extent (see ``_neighbors_kernels._compressed_cells``), so a far outlier is fine.
_MAX_CELLS_PER_AXIS = 2**52


def resolve_neighbors(pts: np.ndarray, *, k: int | None, radius_m: float | None, neighbors: "Neighborhoods | None",
                      workers: int, caller: str, order: str = "'k', 'radius_m' and 'neighbors'") -> "Neighborhoods":
    """The neighbourhoods a descriptor uses: exactly one of ``k``, ``radius_m`` or precomputed ``neighbors``
    (checked against ``pts``), else :class:`DescriptorError` naming ``caller``."""
    given = sum(x is not None for x in (k, radius_m, neighbors))
    if given != 1:
        raise DescriptorError(
            f"Exactly one of the {order} arguments of {caller} must be given. Got {given} of them instead."
        )
    if neighbors is None:
        return find_neighbors(pts, k=k, radius_m=radius_m, workers=workers)
    neighbors.check_for(len(pts), caller)
    return neighbors


def grid_params(pts: np.ndarray, r: float) -> tuple[np.ndarray, float] | None:
    """(origin, cell side) of the radius-``r`` grid search of ``pts`` (N > 0), or None when the grid
    cannot take the cloud (then use a KD-tree)."""
    origin = pts.min(axis=0)
    # Cells a little wider than r, so that rounding can never put two neighbours two cells apart.
    cell_m = r * (1.0 + 1e-8)
    span = float((pts.max(axis=0) - origin).max()) / cell_m
    if not span < _MAX_CELLS_PER_AXIS:
        return None
    if span >= 2**20:  # compressed cells (far outliers): at most 2 per occupied coordinate, keys must fit in int64
        dims = [2.0 * len(np.unique(np.floor(pts[:, a] / cell_m))) + 1.0 for a in range(3)]
        if dims[0] * dims[1] * dims[2] >= 4.0e18:
            return None
    return origin, cell_m


def _grid_radius(pts: np.ndarray, origin: np.ndarray, r: float, cell_m: float, cap: int = 0) -> Neighborhoods:
    grid, counts = grid_bucket_count(pts, origin, cell_m, r)
    capped = bool(cap) and bool(counts.size) and int(counts.max()) > cap
    indptr = np.zeros(len(pts) + 1, dtype=np.int64)
    np.cumsum(np.minimum(counts, cap) if capped else counts, out=indptr[1:])
    # Allocated by numpy (large arrays get transparent huge pages: fewer page faults than numba's).
    indices = np.empty(indptr[-1], dtype=np.int64)
    sqdist = np.empty(indptr[-1])
    grid_fill(*grid, r, cap if capped else 0, indptr, indices, sqdist)
    return Neighborhoods(indptr, indices, sqdist, symmetric=not capped)


def _kdtree_radius(pts: np.ndarray, r: float) -> Neighborhoods:
    tree = cKDTree(pts)
    # All pairs within r, the point itself included (one vectorised call, with the distances).
    pairs = tree.sparse_distance_matrix(tree, r, output_type="ndarray")
    rows = pairs["i"].astype(np.int64)
    keep = (pairs["v"] < r) | (pairs["j"] == pairs["i"])  # PCL's FLANN radius test is strict
    if not keep.all():
        pairs, rows = pairs[keep], rows[keep]
    if rows.size and not (rows[1:] >= rows[:-1]).all():
        order = np.argsort(rows, kind="stable")
        pairs, rows = pairs[order], rows[order]
    indptr = np.zeros(len(pts) + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=len(pts)), out=indptr[1:])
    return Neighborhoods(indptr, pairs["j"].astype(np.int64), pairs["v"] ** 2)
