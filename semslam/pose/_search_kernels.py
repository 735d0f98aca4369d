"""Numba kernels of the global pose search (see :mod:`.search`). Don't call these directly.

Conventions: a hypothesis is ``T_object_scanner = (R, t)`` mapping cluster points (scanner frame) into the
object frame, ``q = R p + t``. The model's distance field is a regular grid (origin ``origin``, cell
``cell_m``) holding, per cell, the offset from the cell centre to the nearest model point as int8 in units
of ``quantum_m`` (-128 when farther than the field's truncation): 3 bytes per cell, so that the grid
stays in the CPU cache (the lookups are random accesses).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, nogil=True)
def _cell_nearest(q0, q1, q2, origin, inv_cell, nx, ny, nz, nearest):
    """(found, x, y, z) of the nearest model point of the cell of (q0, q1, q2); ``origin`` (5,) is the grid
    origin, the cell and the quantum."""
    fi = (q0 - origin[0]) * inv_cell
    fj = (q1 - origin[1]) * inv_cell
    fk = (q2 - origin[2]) * inv_cell
    if fi < 0.0 or fj < 0.0 or fk < 0.0:
        return -1, 0.0, 0.0, 0.0
    i, j, k = int(fi), int(fj), int(fk)
    if i >= nx or j >= ny or k >= nz:
        return -1, 0.0, 0.0, 0.0
    o0 = nearest[i, j, k, 0]
    if o0 == -128:
        return -1, 0.0, 0.0, 0.0
    c, qm = origin[3], origin[4]
    return (1, origin[0] + (i + 0.5) * c + o0 * qm, origin[1] + (j + 0.5) * c + nearest[i, j, k, 1] * qm,
            origin[2] + (k + 0.5) * c + nearest[i, j, k, 2] * qm)


@njit(cache=True, nogil=True)
def field_nearest(points, params, nearest):
    """Stored nearest model point (N, 3) of each point's cell, NaN outside the field."""
    nx, ny, nz = nearest.shape[0], nearest.shape[1], nearest.shape[2]
    inv = 1.0 / params[3]
    out = np.full((points.shape[0], 3), np.nan)
    for n in range(points.shape[0]):
        ok, x, y, z = _cell_nearest(points[n, 0], points[n, 1], points[n, 2], params, inv, nx, ny, nz, nearest)
        if ok > 0:
            out[n, 0], out[n, 1], out[n, 2] = x, y, z
    return out


@njit(cache=True, nogil=True, parallel=True)
def align_and_score(Rs, ts, src, origin, cell_m, nearest, truncations, tau_m):
    """Translation-only alignment of every hypothesis, then its fit cost.

    ``Rs`` (H, 3, 3), ``ts`` (H, 3) (updated in place), ``src`` (N, 3) scanner-frame points, ``origin``
    the field's (origin x y z, cell, quantum), ``nearest`` its int8 offsets. For each
    truncation in ``truncations`` one step moves ``t`` by the mean offset to the nearest model points of the
    source points within that truncation. Returns the fit cost (H,) =
    ``mean_i min(d_i, tau)^2 / tau^2`` in [0, 1] (points outside the field count as ``tau``).
    Hypotheses are independent: they are spread over the cores (same result for any thread count).
    The cell centres per axis and the offsets times the quantum are tabulated first (the same products
    and sums as :func:`_cell_nearest`, so the same bits).
    """
    nx, ny, nz, cx, cy, cz, qv, flat = _tables(origin, nearest)
    H = Rs.shape[0]
    cost = np.empty(H)
    for h in prange(H):
        cost[h] = _align_and_score_one(Rs[h], ts[h], src, origin, cell_m, flat, nx, ny, nz, cx, cy, cz, qv,
                                       truncations, tau_m, np.inf)
    return cost


@njit(cache=True, nogil=True, parallel=True)
def align_and_score_below(Rs, ts, src, origin, cell_m, nearest, truncations, tau_m, bounds):
    """:func:`align_and_score` for a caller that only wants the hypotheses scoring below ``bounds`` (H,): a
    hypothesis whose cost reaches its bound while it is summed stops there and returns that partial cost, which is
    at least the bound and at most the full cost (the sum only grows), so ``cost < bounds`` is the same as with
    :func:`align_and_score`, and so are the costs and translations of those below. The pose search's translation
    starts of a border-cut cluster (dozens per orientation, each kept only when it beats the best so far) spend a
    quarter of their time in the final sum."""
    nx, ny, nz, cx, cy, cz, qv, flat = _tables(origin, nearest)
    H = Rs.shape[0]
    cost = np.empty(H)
    for h in prange(H):
        cost[h] = _align_and_score_one(Rs[h], ts[h], src, origin, cell_m, flat, nx, ny, nz, cx, cy, cz, qv,
                                       truncations, tau_m, bounds[h])
    return cost


@njit(cache=True, inline="always")
def _tables(origin, nearest):
    """The field's shape, cell centres per axis, offsets times the quantum (index + 128) and raveled offsets."""
    nx, ny, nz = nearest.shape[0], nearest.shape[1], nearest.shape[2]
    c, qm = origin[3], origin[4]
    cx, cy, cz = np.empty(nx), np.empty(ny), np.empty(nz)
    for i in range(nx):
        cx[i] = origin[0] + (i + 0.5) * c
    for i in range(ny):
        cy[i] = origin[1] + (i + 0.5) * c
    for i in range(nz):
        cz[i] = origin[2] + (i + 0.5) * c
    qv = np.empty(256)
    for o in range(256):
        qv[o] = (o - 128) * qm
    return nx, ny, nz, cx, cy, cz, qv, nearest.reshape(-1)


@njit(cache=True, inline="always")
def _lookup(p0, p1, p2, o0, o1, o2, inv, nx, ny, nz, flat, cx, cy, cz, qv):
    """:func:`_cell_nearest` on the tables of :func:`align_and_score` (``flat``: the offsets, raveled)."""
    fi = (p0 - o0) * inv
    fj = (p1 - o1) * inv
    fk = (p2 - o2) * inv
    if fi < 0.0 or fj < 0.0 or fk < 0.0:
        return -1, 0.0, 0.0, 0.0
    i, j, k = int(fi), int(fj), int(fk)
    if i >= nx or j >= ny or k >= nz:
        return -1, 0.0, 0.0, 0.0
    b = 3 * ((i * ny + j) * nz + k)
    a0 = flat[b]
    if a0 == -128:
        return -1, 0.0, 0.0, 0.0
    return 1, cx[i] + qv[a0 + 128], cy[j] + qv[flat[b + 1] + 128], cz[k] + qv[flat[b + 2] + 128]


@njit(cache=True, nogil=True)
def _align_and_score_one(R, t, src, origin, cell_m, flat, nx, ny, nz, cx, cy, cz, qv, truncations, tau_m, bound):
    """:func:`align_and_score` of one hypothesis (``t`` (3,) updated in place); the cost summed so far once it
    reaches ``bound`` (checked every 16 points; ``inf``: never)."""
    N = src.shape[0]
    inv = 1.0 / cell_m
    o0, o1, o2 = origin[0], origin[1], origin[2]
    q = np.empty((N, 3))
    for n in range(N):
        for a in range(3):
            q[n, a] = R[a, 0] * src[n, 0] + R[a, 1] * src[n, 1] + R[a, 2] * src[n, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    for it in range(truncations.shape[0]):
        tr2 = truncations[it] * truncations[it]
        s0 = s1 = s2 = 0.0
        cnt = 0
        for n in range(N):
            p0, p1, p2 = q[n, 0] + t0, q[n, 1] + t1, q[n, 2] + t2
            ok, x, y, z = _lookup(p0, p1, p2, o0, o1, o2, inv, nx, ny, nz, flat, cx, cy, cz, qv)
            if ok < 0:
                continue
            d0, d1, d2 = x - p0, y - p1, z - p2
            if d0 * d0 + d1 * d1 + d2 * d2 <= tr2:
                s0 += d0
                s1 += d1
                s2 += d2
                cnt += 1
        if cnt == 0:
            break
        t0 += s0 / cnt
        t1 += s1 / cnt
        t2 += s2 / cnt
    t[0], t[1], t[2] = t0, t1, t2
    tau2 = tau_m * tau_m
    c = 0.0
    for n in range(N):
        p0, p1, p2 = q[n, 0] + t0, q[n, 1] + t1, q[n, 2] + t2
        ok, x, y, z = _lookup(p0, p1, p2, o0, o1, o2, inv, nx, ny, nz, flat, cx, cy, cz, qv)
        if ok < 0:
            c += 1.0
        else:
            d2 = (x - p0) ** 2 + (y - p1) ** 2 + (z - p2) ** 2
            c += min(d2, tau2) / tau2
        if (n & 15) == 15 and c / N >= bound:
            return c / N
    return c / N


@njit(cache=True, nogil=True, parallel=True)
def visibility_cost(Rs, ts, model_pts, model_nrm, viewpoint, F, u0, v0, inv_cell_uv, range_min, tol_m, unseen_bad,
                    occluder_min, camera):
    """Share of the model points predicted visible that contradict the scan, per hypothesis (H,).

    A model point (object frame) is mapped into the scanner frame by the inverse hypothesis; it is predicted visible
    when its normal faces the viewpoint. Its ray is projected on the cluster's range image (gnomonic, rows of ``F`` =
    image axes, z = mean ray; cell ``1 / inv_cell_uv``; ``range_min`` (nu, nv) = smallest observed range around each
    cell, inf where nothing was observed). It contradicts the scan when its cell saw nothing (it should have been
    seen) or when it lies more than ``tol_m`` in front of the observed surface (free space). With ``unseen_bad``
    False (an image of the whole scene, not of the cluster alone) a cell that saw nothing, or a point outside the
    image, is unknown: the point is not counted at all (the scanner did not look there); a point more than ``tol_m``
    behind the observed surface is hidden if an object (``occluder_min``, same grid: the smallest range of the
    scene's objects, not its planes) is in front of it, and contradicts the scan if only a plane is (the object
    would be inside the floor). With a ``camera`` (3,) (a triangulation laser's camera, frame of ``viewpoint``;
    NaN: none) a model point facing away from it or hidden from it by the model (:func:`_camera_hidden`) is not
    predicted visible.

    Computed in the object frame: with ``c = t + R viewpoint`` (the scanner in the object frame) the ray is
    ``r = R^T (p_o - c)``, so the facing test is ``n_o . (p_o - c) < 0``, the range ``|p_o - c|`` and the
    image coordinates ``(F R^T) (p_o - c)``: 3 products per point for the points facing away, 12 for the others.
    """
    H, M = Rs.shape[0], model_pts.shape[0]
    nu, nv = range_min.shape[0], range_min.shape[1]
    out = np.empty(H)
    # no camera: hidden nowhere (read only)
    no_camera = np.zeros(M if np.isnan(camera[0]) or np.isnan(camera[1]) or np.isnan(camera[2]) else 0, np.bool_)
    for h in prange(H):
        R = Rs[h]
        c0 = ts[h, 0] + R[0, 0] * viewpoint[0] + R[0, 1] * viewpoint[1] + R[0, 2] * viewpoint[2]
        c1 = ts[h, 1] + R[1, 0] * viewpoint[0] + R[1, 1] * viewpoint[1] + R[1, 2] * viewpoint[2]
        c2 = ts[h, 2] + R[2, 0] * viewpoint[0] + R[2, 1] * viewpoint[1] + R[2, 2] * viewpoint[2]
        # G = F R^T
        g00 = F[0, 0] * R[0, 0] + F[0, 1] * R[0, 1] + F[0, 2] * R[0, 2]
        g01 = F[0, 0] * R[1, 0] + F[0, 1] * R[1, 1] + F[0, 2] * R[1, 2]
        g02 = F[0, 0] * R[2, 0] + F[0, 1] * R[2, 1] + F[0, 2] * R[2, 2]
        g10 = F[1, 0] * R[0, 0] + F[1, 1] * R[0, 1] + F[1, 2] * R[0, 2]
        g11 = F[1, 0] * R[1, 0] + F[1, 1] * R[1, 1] + F[1, 2] * R[1, 2]
        g12 = F[1, 0] * R[2, 0] + F[1, 1] * R[2, 1] + F[1, 2] * R[2, 2]
        g20 = F[2, 0] * R[0, 0] + F[2, 1] * R[0, 1] + F[2, 2] * R[0, 2]
        g21 = F[2, 0] * R[1, 0] + F[2, 1] * R[1, 1] + F[2, 2] * R[1, 2]
        g22 = F[2, 0] * R[2, 0] + F[2, 1] * R[2, 1] + F[2, 2] * R[2, 2]
        hidden = _camera_hidden(R, ts[h], model_pts, model_nrm, camera, 1.0 / inv_cell_uv, tol_m, no_camera)
        n_front = 0
        n_bad = 0
        for m in range(M):
            a0 = model_pts[m, 0] - c0
            a1 = model_pts[m, 1] - c1
            a2 = model_pts[m, 2] - c2
            # facing away, or where the camera cannot see the laser's spot: no return expected
            if model_nrm[m, 0] * a0 + model_nrm[m, 1] * a1 + model_nrm[m, 2] * a2 >= 0.0 or hidden[m]:
                continue
            n_front += 1
            z = g20 * a0 + g21 * a1 + g22 * a2
            if z <= 1e-9:
                n_bad += 1
                continue
            u = (g00 * a0 + g01 * a1 + g02 * a2) / z
            v = (g10 * a0 + g11 * a1 + g12 * a2) / z
            fi = np.floor((u - u0) * inv_cell_uv)
            fj = np.floor((v - v0) * inv_cell_uv)
            if not (fi >= 0.0 and fj >= 0.0 and fi < nu and fj < nv):  # (NaN-safe)
                if unseen_bad:
                    n_bad += 1
                else:
                    n_front -= 1
                continue
            ro = range_min[int(fi), int(fj)]
            if not np.isfinite(ro):
                if unseen_bad:
                    n_bad += 1
                else:
                    n_front -= 1
                continue
            d = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            if d < ro - tol_m:
                n_bad += 1
            elif not unseen_bad and d > ro + tol_m and not occluder_min[int(fi), int(fj)] <= d + tol_m:
                n_bad += 1
        out[h] = n_bad / max(n_front, 1)
    return out


@njit(cache=True, nogil=True)
def _camera_hidden(R, t, model_pts, model_nrm, camera, cell_rad, tol_m, no_camera):
    """Per model point (M,): True where the camera (scanner frame; NaN: none, and ``no_camera``, the caller's
    all-False array of M, is returned) cannot see it under the hypothesis ``(R, t)`` (object <- scanner): it faces
    away from the camera, or another model point lies in front of it along the camera's ray. The model is splatted
    into a z-buffer about the camera's ray to the model's centre (gnomonic, angular cell ``cell_rad``: the range
    image's); a point is hidden when the smallest camera range over its 3 x 3 cells is nearer than its own by more
    than ``tol_m`` plus two cell footprints (a steep surface does not hide itself)."""
    M = model_pts.shape[0]
    if len(no_camera) == M:  # no camera (or no model point)
        return no_camera
    hidden = np.zeros(M, dtype=np.bool_)
    k0 = t[0] + R[0, 0] * camera[0] + R[0, 1] * camera[1] + R[0, 2] * camera[2]  # the camera in the object frame
    k1 = t[1] + R[1, 0] * camera[0] + R[1, 1] * camera[1] + R[1, 2] * camera[2]
    k2 = t[2] + R[2, 0] * camera[0] + R[2, 1] * camera[1] + R[2, 2] * camera[2]
    # the model's bounding sphere about its centroid, in loops (array expressions bring numba's shape-error and
    # reduction code, ~200 kB that a cold process loads from the cache)
    e0 = e1 = e2 = 0.0
    for m in range(M):
        e0 += model_pts[m, 0]
        e1 += model_pts[m, 1]
        e2 += model_pts[m, 2]
    e0, e1, e2 = e0 / M, e1 / M, e2 / M
    r2 = 0.0
    for m in range(M):
        r2 = max(r2, (model_pts[m, 0] - e0) ** 2 + (model_pts[m, 1] - e1) ** 2 + (model_pts[m, 2] - e2) ** 2)
    z0, z1, z2 = e0 - k0, e1 - k1, e2 - k2
    d2 = z0 * z0 + z1 * z1 + z2 * z2
    if d2 <= 1.0001 * r2 or cell_rad <= 0.0:  # the camera inside the model's sphere: no image of it
        return hidden
    dn = np.sqrt(d2)
    z0, z1, z2 = z0 / dn, z1 / dn, z2 / dn
    # image axes x, y orthogonal to z
    if abs(z2) < 0.9:
        x0, x1, x2 = z1, -z0, 0.0  # z x (0, 0, 1)
    else:
        x0, x1, x2 = 0.0, z2, -z1  # z x (1, 0, 0)
    xn = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    x0, x1, x2 = x0 / xn, x1 / xn, x2 / xn
    y0, y1, y2 = z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0
    half = np.sqrt(r2 / (d2 - r2)) * 1.05 + 2.0 * cell_rad  # tan of the model's half angle, with a margin
    n = min(int(np.ceil(2.0 * half / cell_rad)) + 1, 512)
    cell = 2.0 * half / (n - 1)
    zbuf = np.full((n, n), np.inf)
    ii = np.full(M, -1, np.int64)
    jj = np.zeros(M, np.int64)
    rc = np.empty(M)
    for m in range(M):
        a0 = model_pts[m, 0] - k0
        a1 = model_pts[m, 1] - k1
        a2 = model_pts[m, 2] - k2
        if model_nrm[m, 0] * a0 + model_nrm[m, 1] * a1 + model_nrm[m, 2] * a2 >= 0.0:  # facing away from the camera
            hidden[m] = True
            continue
        z = z0 * a0 + z1 * a1 + z2 * a2
        if z <= 1e-9:
            hidden[m] = True
            continue
        fi = np.floor(((x0 * a0 + x1 * a1 + x2 * a2) / z + half) / cell)
        fj = np.floor(((y0 * a0 + y1 * a1 + y2 * a2) / z + half) / cell)
        if not (fi >= 0.0 and fj >= 0.0 and fi < n and fj < n):
            continue
        i, j = int(fi), int(fj)
        r = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        ii[m], jj[m], rc[m] = i, j, r
        if r < zbuf[i, j]:
            zbuf[i, j] = r
    for m in range(M):
        i = ii[m]
        if i < 0 or hidden[m]:
            continue
        j = jj[m]
        near = np.inf
        for a in range(max(i - 1, 0), min(i + 2, n)):
            for b in range(max(j - 1, 0), min(j + 2, n)):
                near = min(near, zbuf[a, b])
        if rc[m] > near + tol_m + 2.0 * cell * rc[m]:
            hidden[m] = True
    return hidden


@njit(cache=True, nogil=True, parallel=True)
def grid_nearest(points, model_pts, origin, inv_cell, dims, cell_start, cell_points, bound):
    """Exact nearest model point within ``bound`` of each point (N,): distance (inf beyond) and index
    (``len(model_pts)`` beyond), as ``cKDTree.query(points, k=1, distance_upper_bound=bound)`` returns them
    (same squared-distance arithmetic, so the same bits). The model points are bucketed in cells of edge
    ``1 / inv_cell >= bound`` (``dims`` (3,), ``cell_start`` (C + 1,) CSR offsets into ``cell_points``):
    the 27 cells around a point's cell hold every candidate. The point's own cell is searched first; a
    neighbouring cell is skipped when its box (grown by 1e-9 m against rounding) is farther than the best
    squared distance so far, which starts at ``bound^2`` (exact: a skipped cell holds no point as near as the
    final nearest, so ties are still broken by the smallest index). The points are spread over the cores
    (independent queries: the same result for any thread count)."""
    n, M = points.shape[0], model_pts.shape[0]
    nx, ny, nz = dims[0], dims[1], dims[2]
    dist = np.full(n, np.inf)
    idx = np.full(n, M, np.int64)
    b2 = bound * bound
    cell = 1.0 / inv_cell
    eps = 1e-9
    for q in prange(n):
        x, y, z = points[q, 0], points[q, 1], points[q, 2]
        fi = np.floor((x - origin[0]) * inv_cell)
        fj = np.floor((y - origin[1]) * inv_cell)
        fk = np.floor((z - origin[2]) * inv_cell)
        if fi < -1.0 or fj < -1.0 or fk < -1.0 or fi > nx or fj > ny or fk > nz:
            continue
        ci, cj, ck = int(fi), int(fj), int(fk)
        # distances of the point to its cell's lower and upper faces, less eps (lower bounds)
        lx = x - (origin[0] + ci * cell) - eps
        ly = y - (origin[1] + cj * cell) - eps
        lz = z - (origin[2] + ck * cell) - eps
        ux, uy, uz = cell - lx - 2.0 * eps, cell - ly - 2.0 * eps, cell - lz - 2.0 * eps
        best = b2
        bj = M
        for pass_ in range(2):  # 0: the own cell; 1: its 26 neighbours (pruned)
            for i in range(max(ci - 1, 0), min(ci + 2, nx)):
                gx = 0.0 if i == ci else (lx if i < ci else ux)
                gx = max(gx, 0.0)
                for j in range(max(cj - 1, 0), min(cj + 2, ny)):
                    gy = 0.0 if j == cj else (ly if j < cj else uy)
                    gy = max(gy, 0.0)
                    for k in range(max(ck - 1, 0), min(ck + 2, nz)):
                        own = i == ci and j == cj and k == ck
                        if own != (pass_ == 0):
                            continue
                        if not own:
                            gz = 0.0 if k == ck else (lz if k < ck else uz)
                            gz = max(gz, 0.0)
                            if gx * gx + gy * gy + gz * gz > best:
                                continue
                        c = (i * ny + j) * nz + k
                        for s in range(cell_start[c], cell_start[c + 1]):
                            m = cell_points[s]
                            d0 = x - model_pts[m, 0]
                            d1 = y - model_pts[m, 1]
                            d2 = z - model_pts[m, 2]
                            dd = d0 * d0 + d1 * d1 + d2 * d2
                            if dd < best or (dd == best and m < bj):
                                best = dd
                                bj = m
        if bj < M and best < b2:
            dist[q] = np.sqrt(best)
            idx[q] = bj
    return dist, idx


@njit(cache=True, nogil=True)
def range_image(ij, rng, nu, nv, dilate):
    """Smallest range (nu, nv) over the (2 dilate + 1)^2 cells around each cell (inf where none): the
    scatter-min of ``rng`` (N,) at the cells ``ij`` (N, 2) followed by a min-dilation, in one pass."""
    img = np.full((nu, nv), np.inf)
    for n in range(ij.shape[0]):
        r = rng[n]
        for i in range(max(ij[n, 0] - dilate, 0), min(ij[n, 0] + dilate + 1, nu)):
            for j in range(max(ij[n, 1] - dilate, 0), min(ij[n, 1] + dilate + 1, nv)):
                img[i, j] = min(img[i, j], r)
    return img
