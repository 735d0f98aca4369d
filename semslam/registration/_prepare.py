"""Cloud preparation for :func:`semslam.registration.register`: robust extent, far-outlier crop,
statistical outlier removal, automatic voxel size, and the observability checks (a plane or a line
cannot be registered). Vectorised numpy + scipy; don't call directly."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ..errors import RegistrationError

#: Robust box: the 1st-99th percentile of each coordinate.
ROBUST_PERCENTILES = (1.0, 99.0)
#: Points farther than this many robust extents outside the robust box are dropped as far outliers.
FAR_OUTLIER_EXTENTS = 2.0
#: A cloud is a line when its second covariance eigenvalue is below this fraction of the first, a plane
#: when its third is (thickness below 1 % of the length, as standard deviations).
FLAT_EIGEN_RATIO = 1e-4
#: A cloud is planar for registration when the two smallest eigenvalues of the mean n n^T of its normals
#: sum to less than this (rms angle of the normals to their main direction below ~10 degrees).
PLANAR_NORMAL_SPREAD = 0.03


def robust_box(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) of the 1st-99th percentile box of the points (N, 3), N > 0."""
    lo, hi = np.percentile(pts, ROBUST_PERCENTILES, axis=0)
    return lo, hi


def near_mask(pts: np.ndarray) -> np.ndarray:
    """Points within ``FAR_OUTLIER_EXTENTS`` robust extents (the largest side of the robust box) of it."""
    if len(pts) < 20:
        return np.ones(len(pts), dtype=bool)
    lo, hi = robust_box(pts)
    margin = FAR_OUTLIER_EXTENTS * float((hi - lo).max())
    return ((pts >= lo - margin) & (pts <= hi + margin)).all(axis=1)


def statistical_outlier_mask(pts: np.ndarray, k: int = 20, std_ratio: float = 2.0) -> np.ndarray:
    """PCL's ``StatisticalOutlierRemoval``: keep the points whose mean distance to their ``k`` nearest
    neighbours is at most mean + ``std_ratio`` x std of that distance over the cloud."""
    n = len(pts)
    if n <= k + 1:
        return np.ones(n, dtype=bool)
    d, _ = cKDTree(pts).query(pts, k=k + 1)
    mean_d = d[:, 1:].mean(axis=1)
    return mean_d <= mean_d.mean() + std_ratio * mean_d.std()


def auto_voxel(clouds: list[np.ndarray], spacings: list[float], caps: list[int], downsample) -> float:
    """The voxel leaf (m) for all clouds: at least their point spacing, and coarse enough that cloud ``i``
    keeps at most ``caps[i]`` voxels (grown from the robust extent, a few downsamplings)."""
    voxel = 0.0
    for pts, spacing, max_points in zip(clouds, spacings, caps):
        lo, hi = robust_box(pts)
        diag = float(np.linalg.norm(hi - lo))
        v = max(spacing, diag / math.sqrt(max_points) / 2.0, 1e-9)
        for _ in range(8):
            n = len(downsample(pts, v))
            if n <= max_points:
                break
            v *= 1.05 * math.sqrt(n / max_points)
        voxel = max(voxel, v)
    return voxel


def check_shape_observable(name: str, pts: np.ndarray) -> None:
    """Raise RegistrationError when the (voxelised, cropped) cloud is a line or a plane."""
    if len(pts) < 3:
        return
    eig = np.linalg.eigvalsh(np.cov(pts.T))[::-1]  # descending
    if not eig[0] > 0:
        raise RegistrationError(f"The {name} cloud cannot be registered: all its {len(pts)} points coincide.")
    if eig[1] < FLAT_EIGEN_RATIO * eig[0]:
        raise RegistrationError(
            f"The {name} cloud cannot be registered: it is a line (covariance eigenvalues "
            f"{eig[0]:.3g}, {eig[1]:.3g}, {eig[2]:.3g} m^2: the second is below {FLAT_EIGEN_RATIO:g} x the first), "
            "so rotations about it and translations along it are unobservable.")
    if eig[2] < FLAT_EIGEN_RATIO * eig[0]:
        raise RegistrationError(
            f"The {name} cloud cannot be registered: it is a plane (covariance eigenvalues "
            f"{eig[0]:.3g}, {eig[1]:.3g}, {eig[2]:.3g} m^2: the third is below {FLAT_EIGEN_RATIO:g} x the first), "
            "so translations within it and rotations about its normal are unobservable.")


def check_normals_observable(name: str, normals: np.ndarray) -> None:
    """Raise RegistrationError when (nearly) all the finite normals are parallel: a noisy plane."""
    nrm = normals[np.isfinite(normals).all(axis=1)]
    if len(nrm) < 3:
        raise RegistrationError(f"The {name} cloud cannot be registered: only {len(nrm)} of its points have "
                                "a normal (too few neighbours within the normal radius).")
    eig = np.linalg.eigvalsh(nrm.T @ nrm / len(nrm))  # ascending, sum 1
    if eig[0] + eig[1] < PLANAR_NORMAL_SPREAD:
        raise RegistrationError(
            f"The {name} cloud cannot be registered: it is planar (the normals of its {len(nrm)} voxels all lie "
            f"within ~{math.degrees(math.sqrt(eig[0] + eig[1])):.0f} degrees of one direction; spread "
            f"{eig[0] + eig[1]:.3g} < {PLANAR_NORMAL_SPREAD}), so translations within the plane are unobservable.")
