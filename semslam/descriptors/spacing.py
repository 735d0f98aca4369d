"""The measured point spacing of a cloud: the length unit that makes descriptor settings scale-free.

:func:`point_spacing_m` is the median, over a seeded subsample of the points, of the distance from a
point to its ``k``-th nearest other point (scipy ``cKDTree`` over all the points). A regular grid of
spacing ``s`` gives exactly ``s`` (for ``k`` up to 4 on a square grid, 6 on a cubic one); a surface
sampled at random with density ``rho`` gives about ``sqrt(k / (pi rho))``. The median ignores the few
isolated points and the clumps (duplicates, scan-line overlaps) that a mean would follow.

Used by :func:`semslam.recognition.build_database` to choose the voxel grid and the normal radius of
the descriptors from the data (``"auto"``) rather than from fixed lengths in metres, so that a
database built in millimetres, or from a sparser sensor, is described the same way.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_float_array, as_rng, check_int
from ..errors import DescriptorError

#: Default neighbour rank: the 4 edge neighbours of a square grid all lie at the spacing.
DEFAULT_K = 4
#: Default number of query points (the tree holds every point): the median is then within ~2 % of the
#: full one for surface samples, at ~2 ms for 100,000 points.
DEFAULT_SAMPLE = 2000

__all__ = ["DEFAULT_K", "DEFAULT_SAMPLE", "point_spacing_m"]


def point_spacing_m(points_xyz_m: np.ndarray, *, k: int = DEFAULT_K, sample: int | None = DEFAULT_SAMPLE,
                    seed: int | np.random.Generator | None = 0) -> float:
    """Robust point spacing of a cloud: the median distance to the ``k``-th nearest neighbour.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Finite points, any unit (the result is in the same unit), N >= k + 1.
    k : int, default 4
        Neighbour rank (1 = nearest other point). Duplicated points count as neighbours at distance 0.
    sample : int or None, default 2000
        Number of query points drawn without replacement (seeded) when N is larger; None queries every
        point. The neighbours are always searched among all N points.
    seed : int or Generator, default 0
        Seeds the subsample: the result is reproducible.

    Returns
    -------
    float
        The spacing, > 0, in the points' unit.

    Raises
    ------
    DescriptorError
        Non-finite points, a wrong shape, fewer than ``k + 1`` points, or a zero spacing (more than
        half of the sampled points have ``k`` exact duplicates).
    InputError
        ``k`` or ``sample`` not a positive integer.
    """
    caller = "point_spacing_m"
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller, error=DescriptorError)
    k = check_int("k", k, caller=caller, minimum=1)
    n = len(pts)
    if n < k + 1:
        raise DescriptorError(f"The 'points_xyz_m' argument of {caller} must have at least k + 1 = {k + 1} points "
                              f"to measure a spacing. Got {n} instead.")
    if sample is not None:
        sample = check_int("sample", sample, caller=caller, minimum=1)
    from scipy.spatial import cKDTree

    rng = as_rng(seed, caller=caller)
    if sample is not None and n > sample:
        queries = pts[np.sort(rng.choice(n, size=sample, replace=False))]
    else:
        queries = pts
    # k + 1 neighbours: the query point itself (distance 0) comes first, or a duplicate of it does, and
    # either way column k holds the distance to the k-th nearest OTHER point.
    dist, _ = cKDTree(pts).query(queries, k=k + 1)
    spacing = float(np.median(dist[:, k]))
    if not spacing > 0:
        raise DescriptorError(f"The 'points_xyz_m' argument of {caller} has no measurable spacing: more than half "
                              f"of its points have {k} exact duplicate(s).")
    return spacing
