"""Exact chi-square nearest-view search that does not scan the whole database. Don't use directly: use
:class:`semslam.recognition.Chi2NearestNeighbor`.

The distance is FLANN's (and :mod:`._chi2_kernels`'s) ``d(a, b) = sum_k (a_k - b_k)^2 / (a_k + b_k)`` over
the bins with ``a_k + b_k > 0``, no 1/2 factor: the *triangular discrimination*. Its square root
``rho = sqrt(d)`` is a metric on non-negative vectors (each bin's ``|a - b| / sqrt(a + b)`` is a metric on
[0, inf) and ``rho`` is their Euclidean combination; Topsoe 2000, Oesterreicher & Vincze 2003; the tests check
it on random triples), so the triangle inequality bounds the distances we do not compute.

**Index** (:class:`Chi2Index`, built once by ``fit``):

* bins empty in every stored view are dropped (against them a query bin ``q`` always adds exactly ``q``, a
  per-query constant); the others are reordered by decreasing variance of ``sqrt(x)`` over the views, so that
  partial sums grow fastest; the views are copied in that layout, as float32 when that is lossless (databases
  store float32 histograms), grouped by cluster, block-major (bins 0-31 of every view, then 32-63, ...: the
  first blocks, which decide most abandons, of the views visited together are adjacent in memory);
* the views are grouped into ``K ~ sqrt(N)`` clusters by a few k-means iterations on ``sqrt(x)`` (the
  clustering only affects the speed, never the answer);
* per cluster: its centre ``c`` (the members' mean, in the index's layout and precision), every member's
  ``rho(x, c)`` (members sorted by it) and the radius ``r = max rho(x, c)``.

**Query**: ``rho(q, c)`` for every centre; clusters visited by increasing lower bound ``rho(q, c) - r``, skipped
when it is above ``tau``, the k-th best distance so far (in rho); within a cluster, members visited outward
from ``rho(x, c) = rho(q, c)``, each side until ``|rho(q, c) - rho(x, c)| > tau``. Each member visited gets its
distance summed in the reordered layout, abandoned as soon as the partial sum exceeds the k-th best; only a
member that survives gets the exact distance, summed over the original float64 row exactly as the linear scan
sums it (same operations in the same order, so the same float). The answer (rows, distances bit for bit, ties
to the lower row) is therefore the linear scan's.

**Rounding.** The bound computations (centre distances, reordered and vectorised partial sums) have a relative
error of about ``n_bins * 1e-16`` (1e-13 for ESF); every bound test is made with a relative margin of ``1e-9``
(plus ``1e-150`` absolute, for underflow), so a view is skipped only when its distance is certainly larger than
the k-th best. A NaN bound (overflowing histograms) never skips anything.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

#: Relative margin of every bound test (see the module docstring).
BOUND_MARGIN = 1e-9
#: Absolute margin (covers subnormal results).
ABS_MARGIN = 1e-150
#: Bins between two early-abandon tests of a partial sum.
_STRIDE = 32
#: The bound kernels may reorder and vectorise their sums (~4x faster); never used for a returned distance.
_FAST = {"reassoc", "contract", "arcp", "nsz"}


@njit(cache=True, inline="always")
def chi2_exact(a, b):  # pragma: no cover - compiled
    """``d(a, b)`` summed as :func:`._chi2_kernels.chi2_distance_matrix` sums it (same operations in the same
    order, so the same float)."""
    acc = 0.0
    for k in range(a.shape[0]):
        s = a[k] + b[k]
        diff = a[k] - b[k]
        acc += diff * diff / (s if s > 0.0 else 1.0)
    return acc


@njit(cache=True, nogil=True, fastmath=_FAST)
def chi2_approx(q, x, start):  # pragma: no cover - compiled
    """``start + d(q, x)`` (``x`` float32 or float64, widened exactly) to ~1e-15 relative: for bounds only."""
    acc = 0.0
    for k in range(q.shape[0]):
        xk = np.float64(x[k])
        s = q[k] + xk
        diff = q[k] - xk
        acc += diff * diff / (s if s > 0.0 else 1.0)
    return start + acc


@njit(cache=True, nogil=True, fastmath=_FAST)
def chi2_approx_abandon(q, Xb, pos, start, limit):  # pragma: no cover - compiled
    """``start + d(q, row pos)`` to ~1e-15 relative, for bounds only, or a partial sum > ``limit`` as soon as one
    exceeds it. ``Xb`` (n_blocks, m, _STRIDE) holds the rows block-major (float32 or float64, widened
    exactly), ``q`` (n_blocks * _STRIDE,) is zero-padded like them; blocks have a constant length, which LLVM
    vectorises, and consecutive rows' blocks are adjacent in memory."""
    acc = start
    for b in range(Xb.shape[0]):
        k0 = b * _STRIDE
        part = 0.0
        for t in range(_STRIDE):
            xk = np.float64(Xb[b, pos, t])
            s = q[k0 + t] + xk
            diff = q[k0 + t] - xk
            part += diff * diff / (s if s > 0.0 else 1.0)
        acc += part
        if acc > limit:
            return acc
    return acc


@njit(cache=True, inline="always")
def _before(d1, i1, d2, i2):  # pragma: no cover - compiled
    """(d1, i1) comes before (d2, i2) in the linear scan's order: distance, then row; NaN after everything."""
    if d1 != d1:
        return d2 != d2 and i1 < i2
    if d2 != d2:
        return True
    return d1 < d2 or (d1 == d2 and i1 < i2)


@njit(cache=True, inline="always")
def _insert(best_d, best_i, dist, idx):  # pragma: no cover - compiled
    """Insert (dist, idx) into the sorted top-k lists if it comes before their last entry."""
    k = best_d.shape[0]
    if not _before(dist, idx, best_d[k - 1], best_i[k - 1]):
        return
    p = k - 1
    while p > 0 and _before(dist, idx, best_d[p - 1], best_i[p - 1]):
        best_d[p] = best_d[p - 1]
        best_i[p] = best_i[p - 1]
        p -= 1
    best_d[p] = dist
    best_i[p] = idx


@njit(cache=True, inline="always")
def _skip(bound, tau, scale):  # pragma: no cover - compiled
    """True when ``bound`` (a lower bound of rho) is certainly above ``tau``; ``scale`` sums the magnitudes
    involved. False for NaN."""
    return bound > tau + BOUND_MARGIN * scale + ABS_MARGIN


@njit(cache=True, nogil=True)
def _knn_one(q, X, active, offset_bins, Xb, centers, radius, ptr, members, member_rho, best_d,
             best_i):  # pragma: no cover - compiled
    """k = len(best_d) nearest rows of ``X`` to ``q`` into ``best_d``/``best_i`` (see the module docstring);
    returns the number of rows whose (partial) distance was summed."""
    qa = np.zeros(Xb.shape[0] * _STRIDE)  # the active bins, zero-padded to whole blocks
    for t in range(active.shape[0]):
        qa[t] = q[active[t]]
    offset = 0.0
    for t in range(offset_bins.shape[0]):
        offset += q[offset_bins[t]]
    n_clusters = centers.shape[0]
    dc = np.empty(n_clusters)
    lb = np.empty(n_clusters)
    for c in range(n_clusters):
        dc[c] = math.sqrt(chi2_approx(qa[: active.shape[0]], centers[c], offset))
        lb[c] = dc[c] - radius[c]
    order = np.argsort(lb)
    k = best_d.shape[0]
    for t in range(k):  # empty slots: NaN at row m, after every real entry; tau = NaN skips nothing
        best_d[t] = np.nan
        best_i[t] = X.shape[0]
    n_bounded = 0
    for oc in range(n_clusters):
        c = order[oc]
        tau = math.sqrt(best_d[k - 1])
        if _skip(lb[c], tau, dc[c] + radius[c] + tau):
            continue  # (the later clusters mostly too: a comparison each)
        start, stop = ptr[c], ptr[c + 1]
        lo_, hi_ = start, stop  # first member with rho(x, c) >= rho(q, c)
        while lo_ < hi_:
            mid = (lo_ + hi_) // 2
            if member_rho[mid] < dc[c]:
                lo_ = mid + 1
            else:
                hi_ = mid
        hi = lo_
        lo = lo_ - 1
        while lo >= start or hi < stop:  # outward, nearest rho(x, c) first; each side ends at its first skip
            gap_lo = dc[c] - member_rho[lo] if lo >= start else np.inf
            gap_hi = member_rho[hi] - dc[c] if hi < stop else np.inf
            if gap_lo <= gap_hi:
                gap, pos = gap_lo, lo
            else:
                gap, pos = gap_hi, hi
            limit = best_d[k - 1]
            tau = math.sqrt(limit)
            skip = _skip(gap, tau, dc[c] + member_rho[pos] + tau)
            if pos == lo:
                lo = start - 1 if skip else lo - 1
            else:
                hi = stop if skip else hi + 1
            if skip:
                continue
            n_bounded += 1
            cap = limit + BOUND_MARGIN * limit + ABS_MARGIN
            if limit != limit or chi2_approx_abandon(qa, Xb, pos, offset, cap) <= cap:
                j = members[pos]
                _insert(best_d, best_i, chi2_exact(q, X[j]), j)
    return n_bounded


@njit(cache=True, nogil=True, parallel=True)
def knn_query(Q, X, active, offset_bins, Xb, centers, radius, ptr, members, member_rho, k):  # pragma: no cover
    """k nearest rows of ``X`` (m, d) to every row of ``Q`` (n, d): distances (n, k) ascending, rows (n, k)
    and the number of rows bounded per query (n,). Parallel over the queries."""
    n = Q.shape[0]
    out_d = np.empty((n, k))
    out_i = np.empty((n, k), dtype=np.int64)
    n_bounded = np.empty(n, dtype=np.int64)
    for i in prange(n):
        n_bounded[i] = _knn_one(Q[i], X, active, offset_bins, Xb, centers, radius, ptr, members, member_rho,
                                out_d[i], out_i[i])
    return out_d, out_i, n_bounded


@njit(cache=True, nogil=True)
def knn_query_serial(Q, X, active, offset_bins, Xb, centers, radius, ptr, members, member_rho,
                     k):  # pragma: no cover - compiled
    """:func:`knn_query` on one thread (one query: no parallel-region start-up)."""
    n = Q.shape[0]
    out_d = np.empty((n, k))
    out_i = np.empty((n, k), dtype=np.int64)
    n_bounded = np.empty(n, dtype=np.int64)
    for i in range(n):
        n_bounded[i] = _knn_one(Q[i], X, active, offset_bins, Xb, centers, radius, ptr, members, member_rho,
                                out_d[i], out_i[i])
    return out_d, out_i, n_bounded


@njit(cache=True, nogil=True, parallel=True)
def _rho_to_centers(Xb, centers, labels):  # pragma: no cover - compiled
    """``rho(Xb[j], centers[labels[j]])`` (float64 arithmetic, sequential sums)."""
    out = np.empty(Xb.shape[0])
    for j in prange(Xb.shape[0]):
        acc = 0.0
        c = labels[j]
        for k in range(Xb.shape[1]):
            a = np.float64(Xb[j, k])
            b = np.float64(centers[c, k])
            s = a + b
            diff = a - b
            acc += diff * diff / (s if s > 0.0 else 1.0)
        out[j] = math.sqrt(acc)
    return out


@njit(cache=True, nogil=True)
def _cluster_sums(S, labels, n_clusters):  # pragma: no cover - compiled
    """Per-cluster sums of the rows of ``S`` (float64) and member counts."""
    sums = np.zeros((n_clusters, S.shape[1]))
    counts = np.zeros(n_clusters, dtype=np.int64)
    for j in range(S.shape[0]):
        c = labels[j]
        counts[c] += 1
        for k in range(S.shape[1]):
            sums[c, k] += S[j, k]
    return sums, counts


def _nearest_center(S: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Row of ``C`` nearest (Euclidean) to each row of ``S``, by blocks of float32 matrix products."""
    csq = np.einsum("ij,ij->i", C, C)
    labels = np.empty(len(S), dtype=np.int64)
    for a in range(0, len(S), 8192):
        labels[a:a + 8192] = np.argmin(csq[None, :] - 2.0 * (S[a:a + 8192] @ C.T), axis=1)
    return labels


@njit(cache=True, nogil=True, fastmath=_FAST)
def _kmeanspp_seeds(S, n_seeds, first, u):  # pragma: no cover - compiled
    """k-means++ seeding of the rows of ``S`` (float32): row indices (<= n_seeds; fewer when the rows run out
    of distinct values). ``u`` (n_seeds,) uniform [0, 1) draws pick each next seed."""
    n, d = S.shape
    d2 = np.empty(n)
    seeds = np.empty(n_seeds, dtype=np.int64)
    seeds[0] = first
    for j in range(n):
        acc = 0.0
        for k in range(d):
            t = np.float64(S[j, k]) - np.float64(S[first, k])
            acc += t * t
        d2[j] = acc
    m = 1
    while m < n_seeds:
        total = 0.0
        for j in range(n):
            total += d2[j]
        if total <= 0.0:
            break
        target = u[m] * total
        nxt = n - 1
        run = 0.0
        for j in range(n):
            run += d2[j]
            if run > target:
                nxt = j
                break
        seeds[m] = nxt
        m += 1
        for j in range(n):
            if d2[j] > 0.0:
                acc = 0.0
                for k in range(d):
                    t = np.float64(S[j, k]) - np.float64(S[nxt, k])
                    acc += t * t
                if acc < d2[j]:
                    d2[j] = acc
    return seeds[:m]


def _kmeans_sqrt(Xb: np.ndarray, n_clusters: int, rng: np.random.Generator, n_iter: int) -> np.ndarray:
    """Cluster labels (N,) by Lloyd iterations on ``sqrt(x)`` (the Hellinger embedding, in which the chi-square
    distance is nearly Euclidean), seeded by k-means++ on a sample; empty clusters are dropped, labels
    renumbered 0..K'-1."""
    S = np.sqrt(Xb.astype(np.float32))
    n = len(S)
    sample = np.ascontiguousarray(S[rng.choice(n, size=min(n, 8 * n_clusters), replace=False)])
    seeds = _kmeanspp_seeds(sample, n_clusters, int(rng.integers(len(sample))), rng.random(n_clusters))
    C = sample[seeds].copy()
    # Lloyd iterations on a sample of ~64 rows per cluster, then every row to its nearest centre
    train = S if n <= 64 * len(C) else np.ascontiguousarray(S[np.sort(rng.choice(n, 64 * len(C), replace=False))])
    for _ in range(n_iter):
        sums, counts = _cluster_sums(train, _nearest_center(train, C), len(C))
        keep = counts > 0
        C[keep] = (sums[keep] / counts[keep, None]).astype(np.float32)
    labels = _nearest_center(S, C)
    return np.unique(labels, return_inverse=True)[1].astype(np.int64)


class Chi2Index:
    """The cluster index of the rows of ``X`` (see the module docstring).

    ``X``: C-contiguous float64 (m, d), values >= 0 and finite (checked by the caller); kept by reference.
    ``n_clusters`` defaults to ``sqrt(m)``; ``seed`` seeds the clustering (speed only, never the answer).
    """

    def __init__(self, X: np.ndarray, *, n_clusters: int | None = None, seed: int = 0, n_iter: int = 3) -> None:
        m, d = X.shape
        self.X = X
        occupied = (X > 0).any(axis=0)
        rows = np.random.default_rng(seed).choice(m, size=min(m, 20000), replace=False)
        spread = np.sqrt(X[np.sort(rows)][:, occupied]).var(axis=0)  # a sample is enough to order the bins
        self.active = np.flatnonzero(occupied)[np.argsort(-spread, kind="stable")].astype(np.int64)
        self.offset_bins = np.flatnonzero(~occupied).astype(np.int64)
        Xa = X[:, self.active]
        X32 = Xa.astype(np.float32)
        Xa = X32 if np.array_equal(X32, Xa) else Xa  # float32 when lossless: half the memory traffic
        if n_clusters is None:
            n_clusters = int(round(np.sqrt(m)))
        n_clusters = max(1, min(int(n_clusters), m))
        if n_clusters > 1 and len(self.active):
            labels = _kmeans_sqrt(Xa, n_clusters, np.random.default_rng(seed), n_iter)
        else:
            labels = np.zeros(m, dtype=np.int64)
        K = int(labels.max()) + 1
        sums, counts = _cluster_sums(Xa, labels, K)
        centers = np.ascontiguousarray((sums / counts[:, None]).astype(Xa.dtype))
        rho = _rho_to_centers(Xa, centers, labels)
        order = np.lexsort((np.arange(m), rho, labels))  # by cluster, then rho(x, c), then row
        n_blocks = -(-len(self.active) // _STRIDE)
        Xb = np.zeros((n_blocks, m, _STRIDE), dtype=Xa.dtype)  # block-major: rows' early blocks together
        for b in range(n_blocks):
            block = Xa[order, b * _STRIDE:(b + 1) * _STRIDE]
            Xb[b, :, : block.shape[1]] = block
        self.Xb = Xb
        self.centers = centers
        self.members = order.astype(np.int64)
        self.member_rho = np.ascontiguousarray(rho[order])
        self.ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.radius = self.member_rho[self.ptr[1:] - 1].copy()
        self.n_bounded_ = np.zeros(0, dtype=np.int64)

    @property
    def n_clusters(self) -> int:
        return len(self.centers)

    @property
    def nbytes(self) -> int:
        """Memory held by the index beyond ``X`` (bytes)."""
        return sum(a.nbytes for a in (self.Xb, self.centers, self.members, self.member_rho, self.ptr,
                                      self.radius, self.active, self.offset_bins))

    def knn(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(distances (n, k) ascending, rows (n, k)): the k nearest rows of ``X`` to each row of ``Q``
        (C-contiguous float64 (n, d)), exactly as the linear scan (ties: lower row first). ``n_bounded_``
        keeps, per query, the number of rows whose (partial) distance was summed."""
        fn = knn_query_serial if len(Q) == 1 else knn_query
        d, i, self.n_bounded_ = fn(Q, self.X, self.active, self.offset_bins, self.Xb, self.centers, self.radius,
                                   self.ptr, self.members, self.member_rho, int(k))
        return d, i
