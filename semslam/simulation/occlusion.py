"""Partial occlusion of the objects in a simulated scan, for recognition benchmarks (issue #15: how precision and
recall fall with occlusion).

A foreground occluder with a straight edge (a pipe, a frame member, another part) hides a contiguous side of an
object as the sensor sees it. :func:`occlude_objects` models it on a simulated scan, which carries the true
object of every point (field ``instance``: index into the mission's objects; -1 tank, -2 outliers): for every
object instance in the scan, a random direction in the scanner's angular image (sweep angle ``atan2(x, z)``,
in-line angle ``asin(y / r)``, as :mod:`semslam.recognition.plausibility`) is drawn, and the ``fraction`` of the
object's points that lie farthest along it are removed. The occluder's own returns are not added (the hidden
points are simply missing, as behind an occluder outside the working range), so the only change to the scan is
the missing part of each object. The tank and the outliers are left as they are.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_rng, check_positive
from ..cloud import PointCloud
from ..errors import InputError

__all__ = ["occlude_objects"]


def occlude_objects(cloud: PointCloud, fraction: float, *, seed: int | np.random.Generator = 0,
                    instances=None) -> PointCloud:
    """Remove ``fraction`` of every object's points from one side of it, as seen from the sensor.

    Parameters
    ----------
    cloud : PointCloud
        A simulated scan in the scanner frame with the per-point ``instance`` field.
    fraction : float in [0, 1)
        Share of each object's points hidden (0: the cloud unchanged).
    seed : int or Generator
        Draws the occluder's edge direction of each object (in increasing instance order).
    instances : iterable of int, optional
        The object instances to occlude (default: every instance >= 0 in the scan: database objects and clutter).

    Returns
    -------
    PointCloud
        The kept points, every field kept, in their original order.
    """
    caller = "occlude_objects"
    if not isinstance(cloud, PointCloud):
        raise InputError(f"The 'cloud' argument of {caller} must be a PointCloud. Got {type(cloud).__name__} instead.")
    frac = check_positive("fraction", fraction, caller=caller, allow_zero=True)
    if not frac < 1:
        raise InputError(f"The 'fraction' argument of {caller} must be in [0, 1). Got {fraction!r} instead.")
    if "instance" not in cloud.fields:
        raise InputError(f"The 'cloud' argument of {caller} must be a simulated scan with an 'instance' field. "
                         f"Got fields {sorted(cloud.fields)} instead.")
    rng = as_rng(seed, caller=caller)
    inst = np.asarray(cloud.fields["instance"]).astype(np.int64)
    wanted = np.unique(inst[inst >= 0]) if instances is None else np.unique(np.asarray(list(instances), dtype=np.int64))
    if frac == 0 or wanted.size == 0:
        return cloud
    p = cloud.points_xyz_m - np.asarray(cloud.viewpoint_xyz_m, dtype=float)[None, :]
    r = np.maximum(np.linalg.norm(p, axis=1), 1e-12)
    ang = np.column_stack([np.arctan2(p[:, 0], p[:, 2]), np.arcsin(np.clip(p[:, 1] / r, -1.0, 1.0))])
    keep = np.ones(cloud.n_points, dtype=bool)
    for k in wanted:
        theta = rng.uniform(0.0, 2 * np.pi)  # drawn for every wanted instance: the same seed, the same edges
        idx = np.flatnonzero(inst == k)
        n_hide = int(round(frac * idx.size))
        if n_hide == 0:
            continue
        along = ang[idx] @ np.array([np.cos(theta), np.sin(theta)])
        keep[idx[np.argsort(along, kind="stable")[idx.size - n_hide:]]] = False
    return cloud.select(np.flatnonzero(keep))
