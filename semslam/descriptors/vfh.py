"""Viewpoint Feature Histogram (VFH, 308 bins), as PCL's ``VFHEstimation``, with its version quirks."""

from __future__ import annotations

import numpy as np

from .._validation import as_float_array, check_choice
from ..errors import DescriptorError
from ._vfh_kernels import vfh_f32

VFH_SIZE = 308
VFH_VARIANTS = ("pcl-1.13", "pcl-1.8", "rusu2010")


def compute_vfh(
    points_xyz_m: np.ndarray,
    normals_xyz: np.ndarray,
    *,
    viewpoint_xyz_m=(0.0, 0.0, 0.0),
    variant: str = "pcl-1.13",
    normalize_bins: bool = True,
    normalize_distances: bool = False,
    size_component: bool = False,
) -> np.ndarray:
    """VFH global descriptor of a cluster with normals, as PCL's ``VFHEstimation`` (defaults as PCL's).

    Layout: [f1 0-44 | f2 45-89 | f3 90-134 | f4 135-179 | viewpoint 180-307]. f1..f3 are the pair
    features (see :func:`~semslam.descriptors._vfh_kernels.pair_features_f32`) of the centroid with the
    mean normal (not re-normalised) against every point with its normal; each adds 100/(N-1). The
    viewpoint part bins (n . d + 1)/2 of every normal n into 128 bins, each adding 100/N, where d is
    the direction from the centroid to the viewpoint.

    Every step runs in PCL's precision: points, normals, centroid, mean normal, the pair features
    (``acosf``, ``atan2f``, Eigen's summation order) and the histogram are float32, the bin indices
    double from the float features, so a feature on a bin edge falls in PCL's bin and the output is
    PCL 1.13's bit for bit (:func:`~semslam.descriptors._vfh_kernels.vfh_f32`). Inputs are rounded to
    float32 first, as PCL stores them.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Cluster points (m), finite, N >= 2, in the same frame as the viewpoint.
    normals_xyz : array-like of shape (N, 3)
        Unit normals. Points whose normal is not finite are skipped everywhere: left out of the mean
        normal (as PCL does for a non-dense normal cloud) and of both histograms, and N counts only
        the others. (PCL would bin their NaN features into f1/f2 bin 0 and, undefined, the last
        viewpoint bin.)
    viewpoint_xyz_m : array-like of shape (3,)
        Sensor origin (m).
    variant : {"pcl-1.13", "pcl-1.8", "rusu2010"}
        "pcl-1.13": PCL >= 1.10.1 (f2, f3 binned like the angle f1, so they fill only bins ~15-29;
        view direction normalised as the 4-vector (vp - c, -1)). "pcl-1.8": PCL <= 1.10.0 binning
        floor(45 (f + 1) / 2) of f2, f3 with the same 4-vector view direction. "rusu2010": the legacy
        binning and a true 3-D unit view direction (the paper's definition).
    normalize_bins : bool
        Scale the increments to 100/(N-1) and 100/N (PCL default True); else each point adds 1.
    normalize_distances : bool
        With ``size_component``, bin f4 = |p - c| as floor(45 f4 / dmax) (dmax = largest distance
        from c over every point; PCL variants take sqrt(dmax^2 + 1) because of its 4-vector w); else
        round(100 f4).
    size_component : bool
        Fill the f4 block (PCL default False: bins 135-179 stay zero).

    Returns
    -------
    ndarray of shape (308,), float64
        The float32 histogram, widened. Never NaN.

    Raises
    ------
    DescriptorError
        Bad shapes, non-finite points, fewer than 2 points, or fewer than 2 finite normals.
    """
    caller = "compute_vfh"
    pts, nrm, vp, valid = _checked_inputs(points_xyz_m, normals_xyz, viewpoint_xyz_m, variant, caller)
    # PCL works in float32 (points, normals, features, histogram): so do we, step for step, so that a feature
    # on a bin edge falls in PCL's bin (see vfh_f32). The float32 result is returned as float64.
    hist = np.zeros(VFH_SIZE, dtype=np.float32)
    size_mode = (2 if normalize_distances else 1) if size_component else 0
    status = vfh_f32(np.ascontiguousarray(pts, dtype=np.float32), np.ascontiguousarray(nrm, dtype=np.float32),
                     valid, np.ascontiguousarray(vp, dtype=np.float32), variant != "pcl-1.13",
                     variant != "rusu2010", bool(normalize_bins), size_mode, hist)
    if status == 1:
        raise DescriptorError(f"The 'points_xyz_m' argument of {caller} must hold distinct points.")
    if status == 2:
        raise DescriptorError(
            f"The 'viewpoint_xyz_m' argument of {caller} must differ from the cluster's centroid. Got {vp.tolist()}."
        )
    return hist.astype(np.float64)


def _checked_inputs(
    points_xyz_m, normals_xyz, viewpoint_xyz_m, variant: str, caller: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points, normals and viewpoint of :func:`compute_vfh` as float arrays, and which normals are finite."""
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller, error=DescriptorError)
    nrm = as_float_array("normals_xyz", normals_xyz, (len(pts), 3), caller=caller, finite=False,
                         error=DescriptorError)
    vp = as_float_array("viewpoint_xyz_m", viewpoint_xyz_m, (3,), caller=caller, error=DescriptorError)
    check_choice("variant", variant, VFH_VARIANTS, caller=caller)
    if len(pts) < 2:
        raise DescriptorError(
            f"The 'points_xyz_m' argument of {caller} must have at least 2 points. Got {len(pts)} instead."
        )
    valid = np.isfinite(nrm).all(axis=1)
    n = int(valid.sum())
    if n < 2:
        raise DescriptorError(
            f"The 'normals_xyz' argument of {caller} must have at least 2 finite normals. Got {n} instead."
        )
    return pts, nrm, vp, valid
