"""ICP kernels: PCL-compatible point-to-point ICP (SVD/Umeyama steps, PCL's stopping rules), for reproducing
PCL, and a numba point-to-plane ICP on a precomputed nearest-point grid (:func:`icp_plane_field`, the pose
search's refinement: no per-call overhead, no KD-tree).

Don't call this directly: :func:`semslam.registration.align_icp` with ``method="pcl"`` validates first.
small_gicp (Gauss-Newton) converges to the same minimum but stops elsewhere than PCL, whose
criteria (section 4 of ``design/pcl-algorithms.md``) end the loop on an incremental transform with
``cos(angle) >= 1 - eps`` and ``|t|^2 <= eps``, or on ``|dMSE| < 1e-12``, or at the iteration cap.
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit, prange
from scipy.spatial import cKDTree

from ._coarse_kernels import umeyama_batch


def icp_pcl(src: np.ndarray, tree: cKDTree, T0: np.ndarray, max_corr: float, max_iterations: int,
            transformation_epsilon: float, euclidean_fitness_epsilon: float = -np.inf,
            mse_threshold_absolute: float = 1e-12, min_correspondences: int = 3, deadline: float = np.inf,
            ) -> tuple[np.ndarray, int, bool]:
    """Run PCL's ``IterativeClosestPoint`` loop; returns ``(T_target_source, n_iterations, converged)``.
    Stops, not converged, before an iteration that would start past ``deadline`` (a ``time.perf_counter()`` instant)."""
    tgt = tree.data
    T = np.array(T0, dtype=np.float64)
    moved = src @ T[:3, :3].T + T[:3, 3]
    rot_threshold = 1.0 - transformation_epsilon
    prev_mse = np.finfo(np.float64).max
    n_similar_needed = 0
    for it in range(1, max_iterations + 1):
        if time.perf_counter() >= deadline:
            return T, it - 1, False
        d, j = tree.query(moved, k=1, distance_upper_bound=max_corr)
        ok = d * d <= max_corr * max_corr
        if np.count_nonzero(ok) < min_correspondences:
            return T, it - 1, False
        R, t = umeyama_batch(moved[ok][None], tgt[j[ok]][None])
        R, t = R[0], t[0]
        moved = moved @ R.T + t
        D = np.eye(4)
        D[:3, :3], D[:3, 3] = R, t
        T = D @ T
        if it >= max_iterations:
            return T, it, True
        cos_angle = 0.5 * (np.trace(R) - 1.0)
        if cos_angle >= rot_threshold and t @ t <= transformation_epsilon and n_similar_needed == 0:
            return T, it, True
        mse = float(np.mean(d[ok] ** 2))
        if abs(mse - prev_mse) < mse_threshold_absolute:
            return T, it, True
        if abs(mse - prev_mse) / prev_mse < euclidean_fitness_epsilon:
            return T, it, True
        prev_mse = mse
    return T, max_iterations, True


@njit(cache=True, nogil=True)
def _pairs(src, T, params, index, model_pts, model_nrm, mc2, pair):
    """Correspondence of every source point under ``T`` (row of the target point or -1) in ``pair``; returns
    the number of pairs."""
    nx, ny, nz = index.shape[0], index.shape[1], index.shape[2]
    inv = 1.0 / params[3]
    n_pairs = 0
    for i in range(src.shape[0]):
        pair[i] = -1
        p0 = T[0, 0] * src[i, 0] + T[0, 1] * src[i, 1] + T[0, 2] * src[i, 2] + T[0, 3]
        p1 = T[1, 0] * src[i, 0] + T[1, 1] * src[i, 1] + T[1, 2] * src[i, 2] + T[1, 3]
        p2 = T[2, 0] * src[i, 0] + T[2, 1] * src[i, 1] + T[2, 2] * src[i, 2] + T[2, 3]
        fi = (p0 - params[0]) * inv
        fj = (p1 - params[1]) * inv
        fk = (p2 - params[2]) * inv
        if fi < 0.0 or fj < 0.0 or fk < 0.0:
            continue
        a, b, c = int(fi), int(fj), int(fk)
        if a >= nx or b >= ny or c >= nz:
            continue
        best, m = np.inf, -1
        for k in range(index.shape[3]):  # nearest of the cell's candidates
            j = index[a, b, c, k]
            if j < 0:
                break
            d0, d1, d2 = p0 - model_pts[j, 0], p1 - model_pts[j, 1], p2 - model_pts[j, 2]
            d = d0 * d0 + d1 * d1 + d2 * d2
            if d < best:
                best, m = d, j
        if m < 0 or best > mc2:
            continue
        pair[i] = m
        n_pairs += 1
    return n_pairs


@njit(cache=True, nogil=True)
def _plane_error(src, T, model_pts, model_nrm, pair):
    """small_gicp's point-to-plane error of the pairs ``pair`` under ``T``: ``sum 0.5 |n * (q - T s)|^2``
    (element-wise product with the target normal)."""
    e = 0.0
    for i in range(src.shape[0]):
        m = pair[i]
        if m < 0:
            continue
        for a in range(3):
            p = T[a, 0] * src[i, 0] + T[a, 1] * src[i, 1] + T[a, 2] * src[i, 2] + T[a, 3]
            r = model_nrm[m, a] * (model_pts[m, a] - p)
            e += 0.5 * r * r
    return e


@njit(cache=True, nogil=True)
def _plane_normal_equations(src, T, model_pts, model_nrm, pair, H, g, J):
    """The Gauss-Newton system of the point-to-plane error of the pairs ``pair`` under ``T`` (right perturbation
    ``(phi, rho)``, see :func:`icp_plane_field`): ``H`` (6, 6) = sum J^T J and ``g`` (6,) = sum J^T r written in
    place (``J`` (6,) is scratch); returns the error ``sum 0.5 r^2``."""
    H[:] = 0.0
    g[:] = 0.0
    e = 0.0
    for i in range(src.shape[0]):
        m = pair[i]
        if m < 0:
            continue
        x0, x1, x2 = src[i, 0], src[i, 1], src[i, 2]
        for a in range(3):  # one row per axis: e_a = n_a (q_a - (T s)_a)
            na = model_nrm[m, a]
            p = T[a, 0] * x0 + T[a, 1] * x1 + T[a, 2] * x2 + T[a, 3]
            r = na * (model_pts[m, a] - p)
            # d e_a / d phi = n_a (R [s]x)_a ; d e_a / d rho = -n_a R_a
            J[0] = na * (T[a, 1] * x2 - T[a, 2] * x1)
            J[1] = na * (T[a, 2] * x0 - T[a, 0] * x2)
            J[2] = na * (T[a, 0] * x1 - T[a, 1] * x0)
            J[3], J[4], J[5] = -na * T[a, 0], -na * T[a, 1], -na * T[a, 2]
            for u in range(6):
                g[u] += J[u] * r
                for v in range(u, 6):
                    H[u, v] += J[u] * J[v]
            e += 0.5 * r * r
    for u in range(6):
        for v in range(u):
            H[u, v] = H[v, u]
    return e


@njit(cache=True, nogil=True)
def icp_plane_field(src, T0, params, index, model_pts, model_nrm, max_corr, max_iterations, rot_eps, trans_eps):
    """Point-to-plane ICP with correspondences from a precomputed nearest-point grid.

    ``src`` (N, 3) source points; ``T0`` (4, 4) initial ``T_target_source``; ``params`` the grid's
    (origin x y z, cell, quantum); ``index`` (nx, ny, nz, K) int32: rows of ``model_pts`` / ``model_nrm``
    (M, 3) of the K target points nearest to each cell's centre (-1: none). A source point pairs with the
    nearest of its cell's candidates (its exact nearest neighbour unless that is not among them) when
    they are within ``max_corr``.

    The optimiser is small_gicp's (``small_gicp.align(registration_type="PLANE_ICP")``, which the pose
    search was calibrated with): its point-to-plane error is ``sum 0.5 |n * (q - T s)|^2`` with ``*`` the
    element-wise product (a normal-weighted point-to-point error: it slides less than ``(n . (q - T s))^2``,
    which matters for the separation of the search's hypotheses), minimised by Levenberg-Marquardt on a right
    perturbation ``T <- T Exp(delta)``, ``delta = (phi, rho)`` in the source frame, damping 1e-3 divided
    (multiplied) by 10 after an accepted (rejected) step, a step accepted when it decreases the error of the
    iteration's pairs (the damped 6x6 system solved by Cholesky, LU when not numerically positive definite;
    no allocation per step); stops when ``|phi| < rot_eps`` and ``|rho| < trans_eps``, or after
    ``max_iterations``.
    Returns ``(T, iterations, converged, n_pairs)``.
    """
    T = T0.copy()
    N = src.shape[0]
    mc2 = max_corr * max_corr
    converged = False
    it = 0
    n_pairs = 0
    lam = 1e-3
    pair = np.empty(N, np.int64)
    H = np.empty((6, 6))
    g = np.empty(6)
    J = np.empty(6)
    A = np.empty((6, 6))
    delta = np.zeros(6)
    E = np.empty((4, 4))
    T_new = np.empty((4, 4))
    for it in range(max_iterations):
        n_pairs = _pairs(src, T, params, index, model_pts, model_nrm, mc2, pair)
        e = _plane_normal_equations(src, T, model_pts, model_nrm, pair, H, g, J)
        success = False
        for _ in range(10):
            _damped_step(H, g, lam, A, delta)
            _exp_se3_into(delta, E)
            _matmul44(T, E, T_new)
            if _plane_error(src, T_new, model_pts, model_nrm, pair) < e:
                T, T_new = T_new, T
                lam /= 10.0
                success = True
                converged = (np.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2) < rot_eps
                             and np.sqrt(delta[3] ** 2 + delta[4] ** 2 + delta[5] ** 2) < trans_eps)
                break
            lam *= 10.0
        if not success or converged:
            break
    return T, it, converged, n_pairs


@njit(cache=True, nogil=True, parallel=True)
def icp_plane_field_batch(src, T0s, params, index, model_pts, model_nrm, max_corr, max_iterations, rot_eps,
                          trans_eps):
    """:func:`icp_plane_field` from each of ``T0s`` (H, 4, 4), the runs spread over the cores (independent:
    the same results as one call per start). Returns ``(Ts (H, 4, 4), iterations (H,), converged (H,),
    n_pairs (H,))``."""
    H = T0s.shape[0]
    Ts = np.empty((H, 4, 4))
    its = np.empty(H, np.int64)
    conv = np.empty(H, np.bool_)
    n_pairs = np.empty(H, np.int64)
    for h in prange(H):
        T, it, c, n = icp_plane_field(src, T0s[h], params, index, model_pts, model_nrm, max_corr, max_iterations,
                                      rot_eps, trans_eps)
        for a in range(4):  # element-wise: a slice assignment would bring numba's shape-error code
            for b in range(4):
                Ts[h, a, b] = T[a, b]
        its[h] = it
        conv[h] = c
        n_pairs[h] = n
    return Ts, its, conv, n_pairs


@njit(cache=True, nogil=True)
def _solve_spd6(A, g, out):
    """``out = -A^-1 g`` for a symmetric positive definite 6x6 ``A`` by Cholesky (``A`` overwritten by its
    factor); False (``out`` undefined) when a pivot is not positive."""
    for j in range(6):
        d = A[j, j]
        for k in range(j):
            d -= A[j, k] * A[j, k]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        A[j, j] = d
        for i in range(j + 1, 6):
            v = A[i, j]
            for k in range(j):
                v -= A[i, k] * A[j, k]
            A[i, j] = v / d
    for i in range(6):  # L y = -g
        v = -g[i]
        for k in range(i):
            v -= A[i, k] * out[k]
        out[i] = v / A[i, i]
    for i in range(5, -1, -1):  # L^T x = y
        v = out[i]
        for k in range(i + 1, 6):
            v -= A[k, i] * out[k]
        out[i] = v / A[i, i]
    return True


@njit(cache=True, nogil=True)
def _damped_step(H, g, lam, A, delta):
    """The Levenberg-Marquardt step ``delta = -(H + lam I)^-1 g`` (6x6; ``A`` scratch): Cholesky, LU when the
    damped system is not numerically positive definite (on ``H + lam I`` again: the failed Cholesky overwrote
    ``A``). Element by element, see :func:`_solve_lu6` on code size."""
    for u in range(6):
        for v in range(6):
            A[u, v] = H[u, v]
        A[u, u] += lam
    if not _solve_spd6(A, g, delta):
        for u in range(6):
            for v in range(6):
                A[u, v] = H[u, v]
            A[u, u] += lam
        _solve_lu6(A, g, delta)


@njit(cache=True, nogil=True)
def _solve_lu6(A, g, out):
    """``out = -A^-1 g`` for a 6x6 ``A`` by LU with partial pivoting (LAPACK's ``getrf``/``getrs`` order;
    ``A`` overwritten). A zero pivot (a singular system) gives a zero step, which the damping then grows past.
    Written out rather than ``np.linalg.solve``: that brings ~200 kB of code into every kernel calling this,
    which a cold process loads from numba's cache (issue #29's cold-start budget)."""
    piv = np.empty(6, np.int64)
    for i in range(6):
        out[i] = -g[i]
    for j in range(6):
        p = j
        for i in range(j + 1, 6):
            if abs(A[i, j]) > abs(A[p, j]):
                p = i
        if A[p, j] == 0.0:
            for i in range(6):
                out[i] = 0.0
            return
        piv[j] = p
        if p != j:
            for k in range(6):
                A[j, k], A[p, k] = A[p, k], A[j, k]
        for i in range(j + 1, 6):
            A[i, j] /= A[j, j]
            for k in range(j + 1, 6):
                A[i, k] -= A[i, j] * A[j, k]
    for j in range(6):  # the rows of the right-hand side swapped as A's, in order
        p = piv[j]
        if p != j:
            out[j], out[p] = out[p], out[j]
    for i in range(6):  # L y = b (unit diagonal)
        for k in range(i):
            out[i] -= A[i, k] * out[k]
    for i in range(5, -1, -1):  # U x = y
        for k in range(i + 1, 6):
            out[i] -= A[i, k] * out[k]
        out[i] /= A[i, i]


@njit(cache=True, nogil=True)
def _matmul44(A, B, out):
    """``out = A @ B`` for 4x4 rigid transforms (last rows [0 0 0 1])."""
    for i in range(3):
        for j in range(4):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
        out[i, 3] += A[i, 3]
    out[3, 0] = out[3, 1] = out[3, 2] = 0.0
    out[3, 3] = 1.0


@njit(cache=True, nogil=True)
def _exp_se3_into(delta, T):
    """``Exp`` of ``delta = (phi, rho)`` (rotation vector, then translation; Rodrigues and the SE(3) V matrix)
    written into ``T`` (4, 4) without allocations."""
    w0, w1, w2 = delta[0], delta[1], delta[2]
    ang = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    for a in range(4):
        for b in range(4):
            T[a, b] = 1.0 if a == b else 0.0
    if ang >= 1e-12:  # Rodrigues
        k0, k1, k2 = w0 / ang, w1 / ang, w2 / ang
        s, c = np.sin(ang), np.cos(ang)
        C = 1.0 - c
        T[0, 0] = c + k0 * k0 * C
        T[0, 1] = k0 * k1 * C - k2 * s
        T[0, 2] = k0 * k2 * C + k1 * s
        T[1, 0] = k1 * k0 * C + k2 * s
        T[1, 1] = c + k1 * k1 * C
        T[1, 2] = k1 * k2 * C - k0 * s
        T[2, 0] = k2 * k0 * C - k1 * s
        T[2, 1] = k2 * k1 * C + k0 * s
        T[2, 2] = c + k2 * k2 * C
    # V = I + b K + c K^2 with K = [w]x, K^2 = w w^T - |w|^2 I
    if ang < 1e-10:
        b, cc = 0.5, 0.0
    else:
        b, cc = (1.0 - np.cos(ang)) / ang ** 2, (ang - np.sin(ang)) / ang ** 3
    r0, r1, r2 = delta[3], delta[4], delta[5]
    wr = w0 * r0 + w1 * r1 + w2 * r2
    ww = w0 * w0 + w1 * w1 + w2 * w2
    # K r = w x r
    x0, x1, x2 = w1 * r2 - w2 * r1, w2 * r0 - w0 * r2, w0 * r1 - w1 * r0
    T[0, 3] = r0 + b * x0 + cc * (w0 * wr - ww * r0)
    T[1, 3] = r1 + b * x1 + cc * (w1 * wr - ww * r1)
    T[2, 3] = r2 + b * x2 + cc * (w2 * wr - ww * r2)
