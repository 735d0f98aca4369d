"""Fast Point Feature Histograms (FPFH, 33 bins per point) as PCL's ``FPFHEstimation``."""

from __future__ import annotations

import numpy as np

from .._validation import as_float_array, check_choice, check_int, check_positive
from ..errors import DescriptorError, InputError
from ._fpfh_kernels import streamed_fpfh
from ._pair_kernels import fpfh_from_spfh, spfh, spfh_symmetric
from .neighbors import Neighborhoods, grid_params, resolve_neighbors


def compute_spfh(
    points_xyz_m: np.ndarray,
    normals_xyz: np.ndarray,
    *,
    neighbors: Neighborhoods,
    nan_normals: str = "pcl",
) -> np.ndarray:
    """Simplified PFH (N, 33) of every point over the given neighbourhoods (PCL's
    ``computePointSPFHSignature``): blocks f1 | f2 | f3 of 11 bins, each summing to 100 over the
    neighbours (0 when there are none). ``nan_normals`` as in :func:`compute_fpfh`."""
    caller = "compute_spfh"
    pts, nrm = _check(points_xyz_m, normals_xyz, caller)
    check_choice("nan_normals", nan_normals, ("pcl", "skip"), caller=caller)
    neighbors.check_for(len(pts), caller)
    return _spfh(pts, nrm, neighbors, nan_normals)


def compute_fpfh(
    points_xyz_m: np.ndarray,
    normals_xyz: np.ndarray,
    *,
    radius_m: float | None = None,
    k: int | None = None,
    neighbors: Neighborhoods | None = None,
    nan_normals: str = "pcl",
    workers: int = -1,
    max_neighbors: int | None = None,
) -> np.ndarray:
    """FPFH descriptors of every point, as PCL 1.13's ``FPFHEstimation`` (33 bins: f1 | f2 | f3).

    SPFH of every point over its neighbourhood (each neighbour adds 100/(k-1), k counting the point),
    then FPFH(p) = sum over neighbours q at non-zero distance of SPFH(q) / |p - q|^2; p's own SPFH is
    not added (unlike Rusu 2009's formula). Each 11-bin block is rescaled to sum to 100.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points (m), finite.
    normals_xyz : array-like of shape (N, 3)
        Unit normals; NaN rows (points where normals could not be estimated) are allowed, see
        ``nan_normals``.
    radius_m : float, optional
        Search radius (m), PCL's ``setRadiusSearch``. Exactly one of ``radius_m``, ``k`` and
        ``neighbors`` must be given.
    k : int, optional
        Number of nearest neighbours (point included), PCL's ``setKSearch``.
    neighbors : Neighborhoods, optional
        Precomputed neighbourhoods (e.g. shared with :func:`estimate_normals`).
    nan_normals : {"pcl", "skip"}
        "pcl" (default) does what PCL 1.13 does: a pair involving a NaN normal still counts, and its
        NaN angle features fall in bin 0 (x86's integer conversion of NaN, clamped). "skip" leaves
        points with a NaN normal out of every neighbourhood (they add nothing to their neighbours'
        SPFH and 100/(k-1) counts only the others), which avoids that spurious bin-0 mass. Either
        way every point's FPFH is finite: it is computed from its neighbours' SPFH.
    workers : int
        Threads for the KD-tree search (-1 = all).
    max_neighbors : int, optional
        ``k_max``: with ``radius_m``, use at most this many neighbours per point (the point included),
        the nearest ones (FLANN's ``max_nn``); bounds the time on very dense clouds. Points with fewer
        neighbours are unaffected, and when no point reaches the cap the result is exactly the
        uncapped (PCL) one. None (default): no cap, as PCL.

    With ``radius_m`` the neighbourhoods are streamed from the grid search twice instead of being
    stored: memory is O(N) (~0.5 KB per point) whatever the density, and one far outlier costs nothing.

    Returns
    -------
    ndarray of shape (N, 33), float64
        One histogram per point, each block summing to 100; a point without any neighbour at non-zero
        distance gets an all-zero row (as PCL). Never NaN.
    """
    caller = "compute_fpfh"
    pts, nrm = _check(points_xyz_m, normals_xyz, caller)
    cap = 0 if max_neighbors is None else check_int("max_neighbors", max_neighbors, caller=caller, minimum=1)
    if radius_m is not None and k is None and neighbors is None and len(pts):
        r = check_positive("radius_m", radius_m, caller=caller)
        check_choice("nan_normals", nan_normals, ("pcl", "skip"), caller=caller)
        grid = grid_params(pts, r)
        if grid is not None:
            valid = np.isfinite(nrm).all(axis=1)
            out, _, _ = streamed_fpfh(pts, nrm, valid, nan_normals == "skip", grid[0], grid[1], r, cap)
            return out
    elif cap:
        raise InputError(f"The 'max_neighbors' argument of {caller} applies to 'radius_m' searches only. "
                         f"Got max_neighbors={max_neighbors!r} with k={k!r} and neighbors={neighbors!r}.")
    neighbors = resolve_neighbors(pts, k=k, radius_m=radius_m, neighbors=neighbors, workers=workers, caller=caller,
                                  order="'radius_m', 'k' and 'neighbors'")
    check_choice("nan_normals", nan_normals, ("pcl", "skip"), caller=caller)
    hist = _spfh(pts, nrm, neighbors, nan_normals)
    return fpfh_from_spfh(hist, neighbors.indptr, neighbors.indices, neighbors.sqdist_m2)


def _spfh(pts, nrm, neighbors, nan_normals):
    valid = np.isfinite(nrm).all(axis=1)
    kernel = spfh_symmetric if neighbors.symmetric else spfh
    return kernel(pts, nrm, neighbors.indptr, neighbors.indices, valid, nan_normals == "skip")


def _check(points_xyz_m, normals_xyz, caller):
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller, error=DescriptorError)
    nrm = as_float_array("normals_xyz", normals_xyz, (len(pts), 3), caller=caller, finite=False,
                         error=DescriptorError)
    if np.isinf(nrm).any():
        raise DescriptorError(f"The 'normals_xyz' argument of {caller} must not contain infinite values.")
    return pts, nrm
