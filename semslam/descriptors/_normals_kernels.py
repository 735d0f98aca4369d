"""Numba kernels of normal estimation: covariance of each neighbourhood and its smallest
eigenvector in one pass. Don't call directly; use :func:`semslam.descriptors.estimate_normals`."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._neighbors_kernels import _block, _bucket

#: Jacobi sweeps are stopped after this many (4-6 reach machine precision on 3x3 matrices).
MAX_SWEEPS = 32


@njit(cache=True, inline="always")
def _rotate(a, v, p, q, r):  # pragma: no cover - compiled
    """One Jacobi rotation annihilating a[p, q] of the symmetric 3x3 ``a`` (r is the third index);
    accumulates it into the columns of ``v``."""
    apq = a[p, q]
    if apq == 0.0:
        return
    theta = (a[q, q] - a[p, p]) / (2.0 * apq)
    if abs(theta) > 1e150:
        t = 0.5 / theta
    else:
        t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
        if theta < 0.0:
            t = -t
    c = 1.0 / math.sqrt(t * t + 1.0)
    s = t * c
    a[p, p] -= t * apq
    a[q, q] += t * apq
    a[p, q] = a[q, p] = 0.0
    arp = a[r, p]
    arq = a[r, q]
    a[r, p] = a[p, r] = c * arp - s * arq
    a[r, q] = a[q, r] = s * arp + c * arq
    for k in range(3):
        vkp = v[k, p]
        vkq = v[k, q]
        v[k, p] = c * vkp - s * vkq
        v[k, q] = s * vkp + c * vkq


@njit(cache=True, nogil=True)
def _jacobi_eigh3(a, v):  # pragma: no cover - compiled
    """Eigen-decompose the symmetric 3x3 ``a`` in place by cyclic Jacobi rotations: eigenvalues
    end on its diagonal, the eigenvectors in the columns of ``v`` (set to identity first).
    Backward stable like LAPACK's ``syevd`` (errors ~1e-16 of the largest eigenvalue)."""
    for i in range(3):
        for j in range(3):
            v[i, j] = 1.0 if i == j else 0.0
    for _ in range(MAX_SWEEPS):
        off = abs(a[0, 1]) + abs(a[0, 2]) + abs(a[1, 2])
        diag = abs(a[0, 0]) + abs(a[1, 1]) + abs(a[2, 2])
        if off == 0.0 or diag + 10.0 * off == diag:
            # The off-diagonal terms are below a tenth of the diagonal's rounding.
            break
        _rotate(a, v, 0, 1, 2)
        _rotate(a, v, 0, 2, 1)
        _rotate(a, v, 1, 2, 0)


@njit(cache=True, nogil=True)
def normals_from_neighborhoods(points_xyz_m, indptr, indices, viewpoint_xyz_m):  # pragma: no cover
    """Normal and curvature of each CSR neighbourhood, as PCL's ``NormalEstimation``.

    Population covariance (divided by n) around the neighbourhood's mean (two passes: no
    cancellation for far-away clouds), its smallest eigenvector flipped towards the viewpoint, and
    the curvature lambda_0 / (lambda_0 + lambda_1 + lambda_2). Rows with fewer than 3 neighbours
    or a zero covariance get NaN. Returns (normals (N, 3), curvature (N,)).
    """
    n = len(indptr) - 1
    normals = np.empty((n, 3))
    curvature = np.empty(n)
    a = np.empty((3, 3))
    v = np.empty((3, 3))
    for i in range(n):
        _normal_of(points_xyz_m, indices[indptr[i]:indptr[i + 1]], i, viewpoint_xyz_m, a, v, normals, curvature)
    return normals, curvature


@njit(cache=True, nogil=True)
def radius_normals(points_xyz_m, origin, cell_m, radius_m, viewpoint_xyz_m):  # pragma: no cover - compiled
    """:func:`normals_from_neighborhoods` of the radius neighbourhoods of ``find_neighbors(method="grid")``
    in one pass: same neighbours in the same order (so bit-identical normals), without the counting pass and
    the CSR arrays. Returns (normals (N, 3), curvature (N,), n_neighbors (N,) int64)."""
    order, skeys, spts, scells, start, dims = _bucket(points_xyz_m, origin, cell_m)
    n = order.shape[0]
    r2 = radius_m * radius_m
    normals = np.empty((n, 3))
    curvature = np.empty(n)
    counts = np.empty(n, dtype=np.int64)
    a = np.empty((3, 3))
    v = np.empty((3, 3))
    lo = np.empty(9, dtype=np.int64)
    hi = np.empty(9, dtype=np.int64)
    buf = np.empty(n, dtype=np.int64)
    s0 = 0
    while s0 < n:
        s1 = s0 + 1  # the points s0..s1-1 share a cell
        while s1 < n and skeys[s1] == skeys[s0]:
            s1 += 1
        n_cols = _block(s0, skeys, scells, start, dims, lo, hi)
        for s in range(s0, s1):
            px = spts[s, 0]
            py = spts[s, 1]
            pz = spts[s, 2]
            m = 0
            for c in range(n_cols):  # grid_fill's order: column by column, then by sorted position
                for t in range(lo[c], hi[c]):
                    dx = spts[t, 0] - px
                    dy = spts[t, 1] - py
                    dz = spts[t, 2] - pz
                    if (dx * dx + dy * dy) + dz * dz < r2:
                        buf[m] = order[t]
                        m += 1
            i = order[s]
            counts[i] = m
            _normal_of(points_xyz_m, buf[:m], i, viewpoint_xyz_m, a, v, normals, curvature)
        s0 = s1
    return normals, curvature, counts


@njit(cache=True, inline="always")
def _normal_of(points_xyz_m, nbrs, i, viewpoint_xyz_m, a, v, normals, curvature):  # pragma: no cover - compiled
    """Normal and curvature of point i from its neighbours ``nbrs`` (indices into the points), in place."""
    m = nbrs.shape[0]
    normals[i, 0] = normals[i, 1] = normals[i, 2] = np.nan
    curvature[i] = np.nan
    if m < 3:
        return
    cx = 0.0
    cy = 0.0
    cz = 0.0
    for t in range(m):
        j = nbrs[t]
        cx += points_xyz_m[j, 0]
        cy += points_xyz_m[j, 1]
        cz += points_xyz_m[j, 2]
    cx /= m
    cy /= m
    cz /= m
    xx = xy = xz = yy = yz = zz = 0.0
    for t in range(m):
        j = nbrs[t]
        dx = points_xyz_m[j, 0] - cx
        dy = points_xyz_m[j, 1] - cy
        dz = points_xyz_m[j, 2] - cz
        xx += dx * dx
        xy += dx * dy
        xz += dx * dz
        yy += dy * dy
        yz += dy * dz
        zz += dz * dz
    a[0, 0] = xx / m
    a[0, 1] = a[1, 0] = xy / m
    a[0, 2] = a[2, 0] = xz / m
    a[1, 1] = yy / m
    a[1, 2] = a[2, 1] = yz / m
    a[2, 2] = zz / m
    _jacobi_eigh3(a, v)
    k = 0
    if a[1, 1] < a[k, k]:
        k = 1
    if a[2, 2] < a[k, k]:
        k = 2
    trace = (a[0, 0] + a[1, 1]) + a[2, 2]
    if not trace > 0.0:
        return
    curvature[i] = abs(a[k, k] / trace)
    nx = v[0, k]
    ny = v[1, k]
    nz = v[2, k]
    px = viewpoint_xyz_m[0] - points_xyz_m[i, 0]
    py = viewpoint_xyz_m[1] - points_xyz_m[i, 1]
    pz = viewpoint_xyz_m[2] - points_xyz_m[i, 2]
    if px * nx + py * ny + pz * nz < 0.0:
        nx = -nx
        ny = -ny
        nz = -nz
    normals[i, 0] = nx
    normals[i, 1] = ny
    normals[i, 2] = nz
