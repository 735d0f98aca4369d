"""The GTSAM side of the graph backend: keyframes, factors, iSAM2 or batch Levenberg-Marquardt, marginals.

Every call into GTSAM goes through :meth:`GraphBackend._gtsam`, which turns an exception raised inside GTSAM
(an indeterminate system, a refused noise model) into a :class:`~semslam.errors.SlamError` saying what failed.
"""

from __future__ import annotations

import time

import gtsam
import numpy as np

from ...errors import SlamError
from . import factors as fac
from .segment import SegmentAccumulator

BACKENDS = ("isam2", "batch")


class GraphBackend:
    """Holds the factor graph of one run (``kind``: ``isam2`` incremental, ``batch`` solved at the end)."""

    def __init__(self, kind: str, n_v: int, *, relinearize_threshold: float = 0.1, relinearize_skip: int = 1,
                 wildfire: float = 0.001) -> None:
        if kind not in BACKENDS:
            raise SlamError(f"The 'backend' argument of GraphBackend must be one of {BACKENDS}. Got {kind!r} instead.")
        self.kind, self.n_v = kind, n_v
        self.seg = SegmentAccumulator(n_v)
        self.kf_t: list[float] = []
        self._new_f, self._new_v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self._all_f, self._all_v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self.n_factors = 0
        self.n_landmarks = 0
        self.update_s: list[float] = []
        self.result: gtsam.Values | None = None
        self.iterations = 0  #: of the batch optimisation
        self._marg = None
        self._best = None
        if kind == "isam2":
            p = gtsam.ISAM2Params()
            p.setRelinearizeThreshold(relinearize_threshold)
            p.relinearizeSkip = relinearize_skip
            p.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(wildfire))
            p.setFactorization("QR")  # the tightly known calibration states make the Hessian ill-conditioned
            self.isam = gtsam.ISAM2(p)

    # ------------------------------------------------------------------ building
    def _gtsam(self, what: str, fn, *args):
        try:
            return fn(*args)
        except SlamError:
            raise
        except Exception as exc:  # anything raised inside GTSAM (RuntimeError, IndexError, ...)
            raise SlamError(f"The factor-graph backend ({self.kind}) failed in {what}: {type(exc).__name__}: {exc}. "
                            f"The graph has {len(self.kf_t)} keyframes and {self.n_landmarks} landmarks.") from None

    def add_value(self, key: int, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=float).copy()
        self._new_v.insert(key, x)
        if self.kind == "batch":
            self._all_v.insert(key, x)

    def add_factor(self, f) -> None:
        self._new_f.add(f)
        if self.kind == "batch":
            self._all_f.add(f)
        self.n_factors += 1

    @property
    def key(self) -> int:
        return fac.X(len(self.kf_t) - 1)

    def start(self, t: float, x0: np.ndarray, P0: np.ndarray) -> None:
        self.kf_t.append(float(t))
        self.add_value(self.key, x0)
        self.add_factor(fac.prior_factor(self.key, x0, P0, "the initial vehicle state"))

    def keyframe(self, t: float, x_guess: np.ndarray) -> int:
        """The keyframe at ``t`` (the current one when nothing was predicted since): closes the segment."""
        if self.seg.cur_is_k:  # measurements at the keyframe's own stamp: a unary factor now
            self.close_unary()
            return self.key
        k0 = self.key
        A0, A1, b, _ = self.seg.close()
        self.kf_t.append(float(t))
        self.add_value(self.key, x_guess)
        self.add_factor(fac.segment_factor(k0, self.key, A0, A1, b))
        return self.key

    def close_unary(self) -> None:
        """Rows left on the current keyframe alone (measurements at its own stamp after it was made)."""
        if self.seg.cur_is_k and len(self.seg.rows):
            A0, _, b, _ = self.seg.close()
            self.add_factor(fac.segment_factor(self.key, None, A0, None, b))

    def new_landmark(self, x_guess: np.ndarray) -> int:
        key = fac.L(self.n_landmarks)
        self.n_landmarks += 1
        self.add_value(key, x_guess)
        return key

    def flush(self) -> None:
        """iSAM2: one incremental update with the new factors and variables."""
        if self.kind != "isam2" or (self._new_f.size() == 0 and self._new_v.size() == 0):
            return
        t0 = time.perf_counter()
        self._gtsam("an iSAM2 update", self.isam.update, self._new_f, self._new_v)
        self.update_s.append(time.perf_counter() - t0)
        self._best = None
        self._new_f, self._new_v = gtsam.NonlinearFactorGraph(), gtsam.Values()

    # ------------------------------------------------------------------ solving and reading
    def solve(self, max_iterations: int = 50) -> None:
        """Final estimate: iSAM2 (extra relinearisation rounds, then a full back-substitution) or batch LM."""
        if self.kind == "isam2":
            self.flush()
            for _ in range(3):
                self._gtsam("an iSAM2 update", self.isam.update)
            self.result = self._gtsam("the iSAM2 estimate", self.isam.calculateBestEstimate)
            return
        p = gtsam.LevenbergMarquardtParams()
        p.setMaxIterations(max_iterations)
        # from the filter's estimates LM converges in a few iterations; tighter tolerances only chase rounding noise
        # (the 1e-12 floors of segment.py weigh some directions by 1e6)
        p.setRelativeErrorTol(1e-8)
        p.setAbsoluteErrorTol(1e-10)
        p.setLinearSolverType("MULTIFRONTAL_QR")
        opt = self._gtsam("the batch set-up", gtsam.LevenbergMarquardtOptimizer, self._all_f, self._all_v, p)
        t0 = time.perf_counter()
        self.result = self._gtsam("the batch optimisation", opt.optimize)
        self.iterations = int(opt.iterations())
        self.update_s.append(time.perf_counter() - t0)
        # marginals from a QR-eliminated Bayes tree of the optimum (gtsam.Marginals eliminates by Cholesky, which the
        # tightly known calibration states can make indeterminate)
        p2 = gtsam.ISAM2Params()
        p2.setFactorization("QR")
        p2.enableRelinearization = False
        self._marg = gtsam.ISAM2(p2)
        self._gtsam("the batch marginals", self._marg.update, self._all_f, self.result)

    def best(self) -> None:
        """iSAM2: a full back-substitution now (the incremental estimate stops propagating changes below the
        wildfire threshold in parts of the tree far from the new factors); :meth:`vector` reads it until the next
        update."""
        if self.kind == "isam2":
            self._best = self._gtsam("the iSAM2 estimate", self.isam.calculateBestEstimate)

    def vector(self, key: int, final: bool = False) -> np.ndarray:
        if final or self.kind == "batch":
            return np.asarray(self.result.atVector(key))
        if self._best is not None:
            return np.asarray(self._best.atVector(key))
        return np.asarray(self._gtsam("the iSAM2 estimate", self.isam.calculateEstimateVector, key))

    def cov(self, key: int, final: bool = False) -> np.ndarray:
        if self.kind == "batch":
            return np.asarray(self._gtsam("a batch marginal", self._marg.marginalCovariance, key))
        return np.asarray(self._gtsam("an iSAM2 marginal", self.isam.marginalCovariance, key))
