"""Surface normals and curvature by PCA of local neighbourhoods, as PCL's ``NormalEstimation``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_float_array
from ..errors import DescriptorError
from ._normals_kernels import normals_from_neighborhoods, radius_normals
from .neighbors import _MAX_CELLS_PER_AXIS, Neighborhoods, resolve_neighbors


@dataclass(frozen=True, eq=False)
class NormalsResult:
    """Normals estimated at every point.

    Attributes
    ----------
    normals_xyz : ndarray of shape (N, 3)
        Unit normals in the frame of the points, flipped towards the viewpoint. NaN rows where the
        neighbourhood has fewer than 3 points or all its points coincide.
    curvature : ndarray of shape (N,)
        Surface variation lambda_0 / (lambda_0 + lambda_1 + lambda_2) in [0, 1/3]; NaN where the
        normal is NaN.
    n_neighbors : ndarray of shape (N,), int
        Size of each neighbourhood, the point itself included.
    """

    normals_xyz: np.ndarray
    curvature: np.ndarray
    n_neighbors: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """Boolean mask (N,) of points with a finite normal."""
        return np.isfinite(self.normals_xyz[:, 0])


def estimate_normals(
    points_xyz_m: np.ndarray,
    *,
    k: int | None = None,
    radius_m: float | None = None,
    viewpoint_xyz_m=(0.0, 0.0, 0.0),
    neighbors: Neighborhoods | None = None,
    workers: int = -1,
) -> NormalsResult:
    """Estimate normals and curvature like PCL's ``NormalEstimation``.

    The normal at a point is the eigenvector of the smallest eigenvalue of the population covariance
    (divided by n) of its neighbourhood; the k-nearest search includes the point itself. Normals are
    flipped so that ``(viewpoint - p) . n >= 0``.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points (m), finite.
    k : int, optional
        Number of nearest neighbours (point included). Exactly one of ``k``, ``radius_m`` and
        ``neighbors`` must be given.
    radius_m : float, optional
        Neighbourhood radius (m).
    viewpoint_xyz_m : array-like of shape (3,)
        Sensor origin (m) in the frame of the points; PCL's default is the cloud's ``sensor_origin_``.
    neighbors : Neighborhoods, optional
        Precomputed neighbourhoods (from :func:`~semslam.descriptors.find_neighbors`), so that normals
        and FPFH can share one search.
    workers : int
        Threads for the KD-tree search (-1 = all).

    Returns
    -------
    NormalsResult
    """
    caller = "estimate_normals"
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller, error=DescriptorError)
    vp = as_float_array("viewpoint_xyz_m", viewpoint_xyz_m, (3,), caller=caller, error=DescriptorError)
    fused = _fused_radius_normals(pts, vp, k, radius_m, neighbors)
    if fused is not None:
        return fused
    neighbors = resolve_neighbors(pts, k=k, radius_m=radius_m, neighbors=neighbors, workers=workers, caller=caller,
                                  order="'k', 'radius_m' and 'neighbors'")
    normals, curvature = normals_from_neighborhoods(pts, neighbors.indptr, neighbors.indices, vp)
    return NormalsResult(normals, curvature, neighbors.counts)


def _fused_radius_normals(pts: np.ndarray, vp: np.ndarray, k, radius_m, neighbors) -> NormalsResult | None:
    """The radius search on the grid and the normals in one kernel (bit-identical to ``find_neighbors`` then
    ``normals_from_neighborhoods``, ~2x faster on small clusters), when only a valid ``radius_m`` is given and
    ``find_neighbors`` would use its grid; None otherwise (the general path then checks the arguments)."""
    if k is not None or neighbors is not None or radius_m is None or len(pts) == 0:
        return None
    try:
        r = float(radius_m)
    except (TypeError, ValueError):
        return None
    if not (np.isfinite(r) and r > 0):
        return None
    origin = pts.min(axis=0)
    cell_m = r * (1.0 + 1e-8)  # as find_neighbors
    if not float((pts.max(axis=0) - origin).max()) / cell_m < _MAX_CELLS_PER_AXIS:
        return None
    normals, curvature, counts = radius_normals(pts, origin, cell_m, r, vp)
    return NormalsResult(normals, curvature, counts)
