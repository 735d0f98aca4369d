"""Cylinders and planes fitted by RANSAC on points with normals (PCL's ``SACMODEL_CYLINDER`` and
``SACMODEL_NORMAL_PLANE``), used to find the structure an object is attached to (a pipe, a post, a wall) inside
one cluster (:mod:`semslam.pipeline.attached`).

A cylinder hypothesis comes from two points and their normals: the axis is along ``n1 x n2``, through the
closest approach of the two normal lines, with the points' mean distance to it as radius. A plane hypothesis
comes from three points. A point is an inlier when it lies within ``distance_m`` of the surface and its normal
is within ``max_angle_rad`` of the surface's normal there. Hypotheses are scored by their inlier count; the
best one is refitted on its inliers (cylinder: the axis most perpendicular to their normals and a circle fit
across it; plane: least squares) while that explains more points, at most ``refinements`` times.

>>> import numpy as np
>>> from semslam.segmentation.primitives import fit_primitive
>>> # model = fit_primitive(points, normals, "cylinder", distance_m=0.003, seed=0)   # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validation import as_float_array, as_rng, check_choice, check_int, check_positive
from ..errors import InputError

__all__ = ["Primitive", "fit_primitive", "primitive_residuals"]

KINDS = ("cylinder", "plane")


@dataclass(frozen=True, eq=False)
class Primitive:
    """A fitted surface.

    Attributes
    ----------
    kind : {"cylinder", "plane"}
    point_m : ndarray (3,)
        A point of the cylinder's axis, or of the plane.
    direction : ndarray (3,)
        The cylinder's unit axis, or the plane's unit normal.
    radius_m : float
        The cylinder's radius (NaN for a plane).
    inliers : ndarray of int64
        Indices of the points on the surface (within ``distance_m``, normal within ``max_angle_rad``).
    """

    kind: str
    point_m: np.ndarray
    direction: np.ndarray
    radius_m: float
    inliers: np.ndarray = field(repr=False)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "point_m": [float(v) for v in self.point_m],
                "direction": [float(v) for v in self.direction],
                "radius_m": None if self.kind == "plane" else float(self.radius_m), "n_inliers": int(len(self.inliers))}


def primitive_residuals(points: np.ndarray, normals: np.ndarray, kind: str, point_m: np.ndarray,
                        direction: np.ndarray, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(distance to the surface (N,), |cos| of the angle between each normal and the surface normal (N,))."""
    d = points - point_m
    if kind == "plane":
        return np.abs(d @ direction), np.abs(normals @ direction)
    radial = d - np.outer(d @ direction, direction)
    r = np.linalg.norm(radial, axis=1)
    u = radial / np.maximum(r, 1e-12)[:, None]
    return np.abs(r - radius_m), np.abs(np.einsum("ij,ij->i", normals, u))


def _cylinder_hypotheses(p: np.ndarray, n: np.ndarray, i: np.ndarray, j: np.ndarray, lo: float, hi: float):
    """(axis points (H, 3), axes (H, 3), radii (H,)) of the valid two-point hypotheses."""
    p1, p2, n1, n2 = p[i], p[j], n[i], n[j]
    a = np.cross(n1, n2)
    na = np.linalg.norm(a, axis=1)
    ok = na > 0.05  # normals at least ~3 degrees apart
    a = a[ok] / na[ok, None]
    p1, p2, n1, n2 = p1[ok], p2[ok], n1[ok], n2[ok]
    # closest approach of the lines p1 + t n1 and p2 + s n2
    w = p1 - p2
    b = np.einsum("ij,ij->i", n1, n2)
    d1 = np.einsum("ij,ij->i", n1, w)
    d2 = np.einsum("ij,ij->i", n2, w)
    den = 1.0 - b * b
    t = (b * d2 - d1) / den
    s = (d2 - b * d1) / den
    c = 0.5 * ((p1 + t[:, None] * n1) + (p2 + s[:, None] * n2))

    def dist(q):
        v = q - c
        return np.linalg.norm(v - np.einsum("ij,ij->i", v, a)[:, None] * a, axis=1)

    r = 0.5 * (dist(p1) + dist(p2))
    ok = (r >= lo) & (r <= hi) & np.isfinite(r)
    return c[ok], a[ok], r[ok]


def _plane_hypotheses(p: np.ndarray, i: np.ndarray, j: np.ndarray, k: np.ndarray):
    nrm = np.cross(p[j] - p[i], p[k] - p[i])
    nn = np.linalg.norm(nrm, axis=1)
    ok = nn > 1e-12
    return p[i][ok], nrm[ok] / nn[ok, None], np.full(int(ok.sum()), np.nan)


def _circle_across(q: np.ndarray, axis: np.ndarray, centre: np.ndarray, radius: float) -> tuple[np.ndarray, float]:
    """Axis point and radius of the circle (algebraic least squares) through ``q`` projected across ``axis``;
    ``(centre, radius)`` unchanged when the fit is degenerate."""
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    mu = q.mean(axis=0)
    u, v = (q - mu) @ e1, (q - mu) @ e2
    A = np.column_stack([u, v, np.ones_like(u)])
    sol, *_ = np.linalg.lstsq(A, u * u + v * v, rcond=None)
    cu, cv = 0.5 * sol[0], 0.5 * sol[1]
    r2 = sol[2] + cu * cu + cv * cv
    if not (np.isfinite(r2) and r2 > 0):
        return centre, radius
    return mu + cu * e1 + cv * e2, float(np.sqrt(r2))


def _count_inliers(ps: np.ndarray, ns: np.ndarray, kind: str, c: np.ndarray, a: np.ndarray, r: np.ndarray,
                   distance_m: float, cos_min: float) -> np.ndarray:
    """Inliers among ``ps`` (normals ``ns``, zero rows never count) of every hypothesis, 64 at a time."""
    counts = np.empty(len(c), dtype=np.int64)
    for h0 in range(0, len(c), 64):
        cc, aa, rr = c[h0:h0 + 64], a[h0:h0 + 64], r[h0:h0 + 64]
        d = ps[None, :, :] - cc[:, None, :]
        along = np.einsum("hnj,hj->hn", d, aa)
        if kind == "plane":
            dist, cos = np.abs(along), np.abs(np.einsum("nj,hj->hn", ns, aa))
        else:
            radial = d - along[:, :, None] * aa[:, None, :]
            rad = np.sqrt(np.einsum("hnj,hnj->hn", radial, radial))
            dist = np.abs(rad - rr[:, None])
            cos = np.abs(np.einsum("nj,hnj->hn", ns, radial)) / np.maximum(rad, 1e-12)
        counts[h0:h0 + 64] = np.count_nonzero((dist < distance_m) & (cos >= cos_min), axis=1)
    return counts


def fit_primitive(points_xyz_m, normals_xyz, kind: str, *, distance_m: float, max_angle_rad: float = np.radians(30),
                  radius_range_m: tuple[float, float] = (0.005, 0.25), iterations: int = 1000, refinements: int = 3,
                  seed: int | np.random.Generator = 0) -> Primitive | None:
    """The ``kind`` surface ("cylinder" or "plane") with the most inliers among ``points_xyz_m`` (N, 3) with unit
    ``normals_xyz`` (N, 3; rows with NaN are never inliers nor samples), or None when no hypothesis is valid (too
    few points, or no cylinder with its radius in ``radius_range_m``). ``iterations`` hypotheses are drawn with
    ``seed``: the same seed gives the same surface."""
    caller = "fit_primitive"
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller)
    nrm = as_float_array("normals_xyz", normals_xyz, (len(pts), 3), caller=caller, finite=False)
    check_choice("kind", kind, KINDS, caller=caller)
    check_positive("distance_m", distance_m, caller=caller)
    check_positive("max_angle_rad", max_angle_rad, caller=caller)
    check_int("iterations", iterations, caller=caller, minimum=1)
    check_int("refinements", refinements, caller=caller, minimum=0)
    lo, hi = (float(v) for v in radius_range_m)
    if not 0 < lo < hi:
        raise InputError(f"The 'radius_range_m' argument of {caller} must be (low, high) with 0 < low < high. "
                         f"Got {radius_range_m!r} instead.")
    rng = as_rng(seed, caller=caller)
    valid = np.flatnonzero(np.isfinite(nrm).all(axis=1))
    need = 2 if kind == "cylinder" else 3
    if len(valid) < max(need, 3):
        return None
    p, n = pts[valid], nrm[valid]
    draws = np.stack([rng.integers(0, len(valid), size=iterations) for _ in range(need)], axis=1)
    draws = draws[
        (draws[:, 0] != draws[:, 1]) & ((need == 2) | ((draws[:, 0] != draws[:, -1]) & (draws[:, 1] != draws[:, -1])))
    ]
    if kind == "cylinder":
        c, a, r = _cylinder_hypotheses(p, n, draws[:, 0], draws[:, 1], lo, hi)
    else:
        c, a, r = _plane_hypotheses(p, draws[:, 0], draws[:, 1], draws[:, 2])
    if not len(c):
        return None
    cos_min = float(np.cos(max_angle_rad))
    # every hypothesis scored on 300 points, the best 5 % (at least 20) on at most 1,500: the count ranks them
    sub = valid if len(valid) <= 1500 else np.sort(rng.choice(valid, 1500, replace=False))
    ps, ns = pts[sub], np.where(np.isfinite(nrm[sub]), nrm[sub], 0.0)
    coarse = np.arange(len(sub)) if len(sub) <= 300 else np.sort(rng.choice(len(sub), 300, replace=False))
    first = _count_inliers(ps[coarse], ns[coarse], kind, c, a, r, distance_m, cos_min)
    keep = np.sort(np.argsort(-first, kind="stable")[:max(20, len(c) // 20)])
    c, a, r = c[keep], a[keep], r[keep]
    counts = _count_inliers(ps, ns, kind, c, a, r, distance_m, cos_min)
    h = int(np.argmax(counts))  # first best: deterministic
    centre, axis, radius = c[h], a[h], float(r[h])
    finite = np.isfinite(nrm).all(axis=1)
    nz = np.where(finite[:, None], nrm, 0.0)

    def inliers_of(centre, axis, radius):
        dist, cos = primitive_residuals(pts, nz, kind, centre, axis, radius)
        return np.flatnonzero((dist < distance_m) & (cos >= cos_min) & finite)

    inl = inliers_of(centre, axis, radius)
    for _ in range(refinements):  # refit on the inliers; kept while it explains more points
        if len(inl) < need + 1:
            break
        q = pts[inl]
        if kind == "plane":
            c2 = q.mean(axis=0)
            a2, r2 = np.linalg.svd(q - c2, full_matrices=False)[2][-1], float("nan")
        else:  # the axis most perpendicular to the inliers' normals, then a circle fit across it
            m = nz[inl]
            a2 = np.linalg.eigh(m.T @ m)[1][:, 0]
            c2, r2 = _circle_across(q, a2, centre, radius)
        refined = inliers_of(c2, a2, r2)
        if len(refined) <= len(inl):
            break
        centre, axis, radius, inl = c2, a2, r2, refined
    return Primitive(kind, np.asarray(centre, dtype=np.float64), np.asarray(axis, dtype=np.float64),
                     float("nan") if kind == "plane" else radius, inl.astype(np.int64))
