"""Coarse alignment: prerejective RANSAC on feature correspondences (Buch et al. 2013, Holz et al. 2015),
as PCL's ``SampleConsensusPrerejective`` (see ``design/pcl-algorithms.md`` section 4).

Per hypothesis: ``n_samples`` distinct source points; for each, one of its ``k_correspondences`` nearest
target points in feature space, picked at random; polygon pre-rejection on edge-length ratios; Umeyama
(SVD) transform; score = inlier fraction and mean squared distance of the inliers. A hypothesis is kept
when its inlier fraction reaches ``inlier_fraction`` and its error beats the best so far (PCL's rule).
Hypotheses are drawn, pre-rejected, estimated and scored in numpy batches.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .._validation import as_float_array, as_rng, check_choice, check_int, check_positive
from ..errors import InputError, RegistrationError
from ..geometry import RigidTransform, orthonormalize_transform
from . import _coarse_kernels as K
from .result import RegistrationResult, inlier_statistics

_CALLER = "align_prerejective"
_SCORE_CHUNK_POINTS = 1 << 18
_DEADLINE_CHUNK_POINTS = 1 << 16


def align_prerejective(
    source_points: Any, source_features: Any, target_points: Any, target_features: Any, *,
    max_iterations: int = 5000, n_samples: int = 3, k_correspondences: int = 2, similarity: float = 0.6,
    max_correspondence_m: float = float("inf"), inlier_fraction: float = 0.0,
    seed: int | np.random.Generator | None = 0, init_T: Any = None, stop_fraction: float | None = None,
    batch_size: int = 2048, target_tree: cKDTree | None = None, target_feature_tree: cKDTree | None = None,
    selection: str = "error", deadline: float | None = None, on_batch: Any = None,
) -> RegistrationResult:
    """Align ``source_points`` onto ``target_points`` from precomputed point features.

    Parameters
    ----------
    source_points, target_points : array-like of shape (N, 3) and (M, 3)
        Point coordinates (metres), each in its own frame.
    source_features, target_features : array-like of shape (N, D) and (M, D)
        One feature vector per point (FPFH: D = 33). Rows with NaN (points without a normal) are never
        sampled or matched, but their points still count when scoring.
    max_iterations, n_samples : int
        Hypotheses drawn (PCL default 5000; its tutorial uses 50000) and points per hypothesis (>= 3).
    k_correspondences : int
        Each sampled source point is matched to one of its ``k`` nearest target features, at random.
    similarity : float
        Polygon pre-rejection threshold in (0, 1]: every edge-length ratio must be >= ``similarity``.
    max_correspondence_m, inlier_fraction : float
        A transformed source point is an inlier when its nearest target point is closer than
        ``max_correspondence_m``; a hypothesis is accepted when its inlier fraction reaches ``inlier_fraction``.
    seed : int or numpy Generator
        Makes the result reproducible.
    init_T : None, array-like (4, 4), RigidTransform or ``"centroid"``
        An initial guess ``T_target_source``, scored first (as PCL does with a non-identity guess).
        ``"centroid"`` is the translation taking the source centroid onto the target centroid (the
        papers' initialisation). The result falls back to it when no hypothesis is accepted.
    stop_fraction : float, optional
        Stop early once the best accepted hypothesis has at least this inlier fraction (not in PCL:
        ``None`` runs all ``max_iterations``).
    batch_size : int
        Hypotheses processed per numpy batch (memory ~ batch * N * 24 bytes for the survivors).
    target_tree, target_feature_tree : scipy.spatial.cKDTree, optional
        Cached KD-trees of ``target_points`` and ``target_features`` (reused across calls on the same
        target; the target features must then all be finite).
    selection : {"error", "msac"}
        ``"error"`` (PCL): among hypotheses reaching ``inlier_fraction``, the smallest mean squared inlier distance
        wins. ``"msac"``: the smallest truncated cost ``mean(min(d^2, max_correspondence_m^2))`` over all source
        points wins, which rewards more inliers (better on small, self-similar objects; needs a finite
        ``max_correspondence_m``).
    deadline : float, optional
        A ``time.perf_counter()`` instant: no new batch of hypotheses is started after it (the time
        budget of :func:`~semslam.registration.register`); ``extras["budget_exhausted"]`` then says so.
        Hypotheses are then scored in chunks of ~2^16 source points, the deadline checked between them
        (the hypotheses drawn, hence the result without a deadline, do not depend on it).
    on_batch : callable, optional
        Called as ``on_batch(n_drawn)`` after every batch (progress reporting).

    Returns
    -------
    RegistrationResult
        ``T_target_source`` of the best hypothesis, its fitness (inlier fraction) and inlier RMSE.
        ``converged`` is False when no hypothesis reached ``inlier_fraction``; the transform is then the
        initial guess (identity without one). ``extras`` counts hypotheses drawn, pre-rejected and scored.

    Raises
    ------
    InputError
        On badly shaped, non-finite or out-of-range arguments.
    RegistrationError
        When fewer than ``n_samples`` points have finite features.
    """
    t0 = time.perf_counter()
    src, fs, tgt, ft = _checked_clouds(source_points, source_features, target_points, target_features)
    settings = _checked_settings(max_iterations, n_samples, k_correspondences, similarity, max_correspondence_m,
                                 inlier_fraction, stop_fraction, batch_size, selection, deadline)
    rng = as_rng(seed, caller=_CALLER)
    src_ok, tgt_ok = _rows_with_finite_features(fs, ft, settings.n_samples)
    T_init = _initial_guess(init_T, src, tgt)
    tree = target_tree if target_tree is not None else cKDTree(tgt)
    t1 = time.perf_counter()
    nn, k = _feature_neighbours(fs, ft, src_ok, tgt_ok, settings.k_correspondences, target_feature_tree)
    t2 = time.perf_counter()
    search = _run_hypotheses(src, tgt, tree, src_ok, nn, k, T_init, settings, rng, on_batch)
    return _coarse_result(src, tree, search, T_init, settings.max_corr, (t0, t1, t2, time.perf_counter()))


@dataclass(frozen=True)
class _Settings:
    """The checked scalar arguments of :func:`align_prerejective`."""

    max_iterations: int
    n_samples: int
    k_correspondences: int
    similarity: float
    max_corr: float
    inlier_fraction: float
    stop_fraction: float | None
    batch_size: int
    selection: str
    deadline: float | None


@dataclass
class _Search:
    """The running state of the hypothesis loop: the best accepted hypothesis and the counters."""

    best_T: np.ndarray | None = None
    best_err: float = np.inf
    best_frac: float = 0.0
    n_drawn: int = 0
    n_rejected: int = 0
    n_scored: int = 0
    exhausted: bool = False


def _checked_clouds(source_points: Any, source_features: Any, target_points: Any, target_features: Any,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points and features as float arrays of matching shapes (features may hold NaN)."""
    src = as_float_array("source_points", source_points, (None, 3), caller=_CALLER)
    tgt = as_float_array("target_points", target_points, (None, 3), caller=_CALLER)
    fs = as_float_array("source_features", source_features, (len(src), None), caller=_CALLER, finite=False)
    ft = as_float_array("target_features", target_features, (len(tgt), fs.shape[1]), caller=_CALLER, finite=False)
    return src, fs, tgt, ft


def _checked_settings(max_iterations: Any, n_samples: Any, k_correspondences: Any, similarity: Any,
                      max_correspondence_m: Any, inlier_fraction: Any, stop_fraction: Any, batch_size: Any,
                      selection: str, deadline: float | None) -> _Settings:
    """The scalar arguments checked (an InputError naming the first bad one)."""
    max_iterations = check_int("max_iterations", max_iterations, caller=_CALLER, minimum=1)
    n_samples = check_int("n_samples", n_samples, caller=_CALLER, minimum=3)
    k = check_int("k_correspondences", k_correspondences, caller=_CALLER, minimum=1)
    similarity = check_positive("similarity", similarity, caller=_CALLER)
    if similarity > 1:
        raise InputError(f"The 'similarity' argument of {_CALLER} must be in (0, 1]. Got {similarity!r} instead.")
    max_corr = check_positive("max_correspondence_m", max_correspondence_m, caller=_CALLER) \
        if np.isfinite(max_correspondence_m) else float("inf")
    if not (0.0 <= float(inlier_fraction) <= 1.0):
        raise InputError(
            f"The 'inlier_fraction' argument of {_CALLER} must be in [0, 1]. Got {inlier_fraction!r} instead."
        )
    if stop_fraction is not None and not (0.0 < float(stop_fraction) <= 1.0):
        raise InputError(
            f"The 'stop_fraction' argument of {_CALLER} must be None or in (0, 1]. Got {stop_fraction!r} instead."
        )
    batch_size = check_int("batch_size", batch_size, caller=_CALLER, minimum=1)
    check_choice("selection", selection, ("error", "msac"), caller=_CALLER)
    if selection == "msac" and not np.isfinite(max_corr):
        raise InputError(f"The 'selection' argument of {_CALLER} can be 'msac' only with a finite "
                         f"'max_correspondence_m'. Got max_correspondence_m = {max_corr} instead.")
    return _Settings(max_iterations, n_samples, k, similarity, max_corr, float(inlier_fraction), stop_fraction,
                     batch_size, selection, deadline)


def _rows_with_finite_features(fs: np.ndarray, ft: np.ndarray, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the source and target features without NaN; a RegistrationError when too few."""
    src_ok = np.flatnonzero(np.isfinite(fs).all(axis=1))
    tgt_ok = np.flatnonzero(np.isfinite(ft).all(axis=1))
    if len(src_ok) < n_samples or len(tgt_ok) < 1:
        raise RegistrationError(
            f"align_prerejective needs at least {n_samples} source points and 1 target point with finite features. "
            f"Got {len(src_ok)} source and {len(tgt_ok)} target points instead."
        )
    return src_ok, tgt_ok


def _feature_neighbours(fs: np.ndarray, ft: np.ndarray, src_ok: np.ndarray, tgt_ok: np.ndarray, k: int,
                        target_feature_tree: cKDTree | None) -> tuple[np.ndarray, int]:
    """Target rows (len(src_ok), k) of the k nearest target features of every usable source point (the cache
    PCL fills lazily), and k (at most the number of usable target rows)."""
    k = min(k, len(tgt_ok))
    if target_feature_tree is not None and len(tgt_ok) != len(ft):
        raise InputError(f"The 'target_feature_tree' argument of {_CALLER} needs finite target features. "
                         f"Got {len(ft) - len(tgt_ok)} non-finite row(s) instead.")
    ftree = target_feature_tree if target_feature_tree is not None else cKDTree(ft[tgt_ok])
    _, nn = ftree.query(fs[src_ok], k=k)
    return tgt_ok[nn.reshape(len(src_ok), k)], k


def _run_hypotheses(src: np.ndarray, tgt: np.ndarray, tree: cKDTree, src_ok: np.ndarray, nn: np.ndarray, k: int,
                    T_init: np.ndarray | None, s: _Settings, rng: np.random.Generator, on_batch: Any) -> _Search:
    """The initial guess scored, then batches of hypotheses drawn, pre-rejected, estimated and scored until
    ``max_iterations``, the deadline or ``stop_fraction``."""
    n = len(src)
    min_inliers = s.inlier_fraction * n
    state = _Search()
    if T_init is not None:
        frac, err = _score(src, tree, T_init[None], s.max_corr, s.selection)
        if frac[0] * n >= min_inliers:
            state.best_T, state.best_err, state.best_frac = T_init, float(err[0]), float(frac[0])
    while state.n_drawn < s.max_iterations:
        if s.deadline is not None and time.perf_counter() >= s.deadline:
            state.exhausted = True
            break
        if on_batch is not None and state.n_drawn:
            on_batch(state.n_drawn)
        b = min(s.batch_size, s.max_iterations - state.n_drawn)
        state.n_drawn += b
        Ts_all = _draw_hypotheses(src, tgt, src_ok, nn, k, b, s, rng, state)
        if Ts_all is None:
            continue
        _score_hypotheses(src, tree, Ts_all, min_inliers, s, state)
        if state.exhausted:
            break
        if s.stop_fraction is not None and state.best_T is not None and state.best_frac >= s.stop_fraction:
            break
    return state


def _draw_hypotheses(src: np.ndarray, tgt: np.ndarray, src_ok: np.ndarray, nn: np.ndarray, k: int, b: int,
                     s: _Settings, rng: np.random.Generator, state: _Search) -> np.ndarray | None:
    """``b`` samples drawn and pre-rejected (counted in ``state``); the Umeyama transforms (B, 4, 4) of the
    survivors, None when none survived."""
    si = src_ok[K.sample_distinct(rng, len(src_ok), b, s.n_samples)]  # (b, n_samples) source indices
    pick = rng.integers(0, k, size=si.shape) if k > 1 else np.zeros(si.shape, dtype=np.int64)
    ti = nn[np.searchsorted(src_ok, si), pick]
    keep = K.polygon_similar(src[si], tgt[ti], s.similarity)
    state.n_rejected += int(b - keep.sum())
    if not keep.any():
        return None
    R, t = K.umeyama_batch(src[si[keep]], tgt[ti[keep]])
    return K.transforms_from(R, t)


def _score_hypotheses(src: np.ndarray, tree: cKDTree, Ts_all: np.ndarray, min_inliers: float, s: _Settings,
                      state: _Search) -> None:
    """Score ``Ts_all`` and keep the best accepted one in ``state``: in chunks of ~2^16 points, the deadline
    checked between them (same result as one chunk)."""
    n = len(src)
    chunk = len(Ts_all) if s.deadline is None else max(1, _DEADLINE_CHUNK_POINTS // max(1, n))
    for c in range(0, len(Ts_all), chunk):
        if c and s.deadline is not None and time.perf_counter() >= s.deadline:
            state.exhausted = True
            break
        Ts = Ts_all[c:c + chunk]
        frac, err = _score(src, tree, Ts, s.max_corr, s.selection)
        state.n_scored += len(Ts)
        ok = np.flatnonzero((frac * n >= min_inliers) & (err < state.best_err))
        if ok.size:
            j = ok[np.argmin(err[ok])]
            state.best_T, state.best_err, state.best_frac = Ts[j], float(err[j]), float(frac[j])


def _coarse_result(src: np.ndarray, tree: cKDTree, state: _Search, T_init: np.ndarray | None, max_corr: float,
                   times: tuple[float, float, float, float]) -> RegistrationResult:
    """The RegistrationResult of the best hypothesis (the initial guess, else identity, when none was accepted)."""
    t0, t1, t2, t3 = times
    converged = state.best_T is not None
    T = state.best_T if converged else (T_init if T_init is not None else np.eye(4))
    T = _orthonormalise(T)
    fitness, rmse, n_in = inlier_statistics(src @ T[:3, :3].T + T[:3, 3], tree, max_corr)
    return RegistrationResult(
        T_target_source=RigidTransform(T),
        fitness=fitness,
        inlier_rmse_m=rmse,
        n_iterations=state.n_drawn,
        converged=converged,
        n_inliers=n_in,
        max_correspondence_m=max_corr,
        method="prerejective",
        timings_ms={
            "feature_matching": 1e3 * (t2 - t1),
            "ransac": 1e3 * (t3 - t2),
            "total": 1e3 * (time.perf_counter() - t0),
        },
        extras={
            "n_prerejected": state.n_rejected,
            "n_scored": state.n_scored,
            "best_error_m2": state.best_err if converged else None,
            "budget_exhausted": state.exhausted,
        },
    )


def _score(src: np.ndarray, tree: cKDTree, Ts: np.ndarray, max_corr: float, selection: str = "error",
           ) -> tuple[np.ndarray, np.ndarray]:
    """Inlier fraction ``(B,)`` and cost ``(B,)`` of each transform: mean squared inlier distance (inf
    without inliers) for ``"error"``, truncated mean squared distance for ``"msac"``."""
    d = np.empty((len(Ts), len(src)))
    step = max(1, _SCORE_CHUNK_POINTS // max(1, len(src)))
    for s in range(0, len(Ts), step):  # bounded memory: at most ~_SCORE_CHUNK_POINTS points at once
        moved = np.einsum("bij,nj->bni", Ts[s:s + step, :3, :3], src) + Ts[s:s + step, None, :3, 3]
        d[s:s + step] = tree.query(moved.reshape(-1, 3), k=1, distance_upper_bound=max_corr)[0].reshape(-1, len(src))
    inl = d < max_corr
    cnt = inl.sum(axis=1)
    sq = np.where(inl, d * d, 0.0).sum(axis=1)
    if selection == "msac":
        return cnt / len(src), (sq + (len(src) - cnt) * max_corr * max_corr) / len(src)
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.where(cnt > 0, sq / np.maximum(cnt, 1), np.inf)
    return cnt / len(src), err


def _initial_guess(init_T: Any, src: np.ndarray, tgt: np.ndarray) -> np.ndarray | None:
    if init_T is None:
        return None
    if isinstance(init_T, str):
        if init_T != "centroid":
            raise InputError(
                f"The 'init_T' argument of {_CALLER} must be None, 'centroid' or a 4x4 transform. Got {init_T!r} "
                f"instead."
            )
        T = np.eye(4)
        T[:3, 3] = tgt.mean(axis=0) - src.mean(axis=0)
        return T
    T = init_T.matrix if isinstance(init_T, RigidTransform) else RigidTransform(init_T).matrix
    return None if np.allclose(T, np.eye(4)) else np.array(T)


def _orthonormalise(T: np.ndarray) -> np.ndarray:
    return orthonormalize_transform(np.array(T, dtype=np.float64))
