"""The GTSAM side of the graph backend: keyframes, factors, iSAM2 or batch Levenberg-Marquardt, marginals.

Every call into GTSAM goes through :meth:`GraphBackend._gtsam`, which turns an exception raised inside GTSAM
(an indeterminate system, a refused noise model) into a :class:`~semslam.errors.SlamError` saying what failed.

Cost. GTSAM's Python wrapper hands a Python error function (a ``CustomFactor``) a *copy* of the whole ``Values``,
so each linearisation of a ``CustomFactor`` costs O(size of the graph): iSAM2's update time grew linearly with the
dive (9 ms per update at 1,000 landmarks). So iSAM2 holds only native factors: the linear ones
(:func:`~semslam.slam.graph.factors.linear_factor`) and the detection factors linearised here at their variables'
linearisation points (the values the variables were created with, as iSAM2 linearises a new factor), relinearised
here when a variable's estimate moves more than ``relinearize_threshold`` from that point (iSAM2's own rule, checked
on the variables of each update's new detection factors, and on every variable at :meth:`solve`), or a keyframe's
yaw bias (``bias_index``) more than ``bias_threshold`` rad: one threshold over mixed units is 5.7 degrees for the
bias, which left a 5-degree bias' detection factors at the prior's bias (30 runs, 5-degree bias and prior sigma,
surveyed ``elbow_1``: iSAM2's end-of-dive ATE 1.05x batch's; with ``bias_threshold`` 0.005 rad 1.01x, and its
current-time ATE 0.0261 -> 0.0258 m, the EKF's 0.0261 m). With a robust kernel, :meth:`solve` reweights every
detection factor at the final estimate, as batch does. iSAM2's own relinearisation is off (``relinearize_skip`` is
kept for the signature): every factor it holds is linear. Batch keeps the nonlinear factors (Levenberg-Marquardt
relinearises them at every iteration).
"""

from __future__ import annotations

import time

import gtsam
import numpy as np

from ...errors import SlamError
from ...modes import GRAPH_BACKENDS as BACKENDS
from . import factors as fac
from .segment import SegmentAccumulator



class GraphBackend:
    """Holds the factor graph of one run (``kind``: ``isam2`` incremental, ``batch`` solved at the end)."""

    def __init__(self, kind: str, n_v: int, *, relinearize_threshold: float = 0.1, relinearize_skip: int = 1,
                 wildfire: float = 0.001, bias_index: int = -1, bias_threshold: float = 0.005) -> None:
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
        self.last_result = None  #: iSAM2: the ISAM2Result of the last update (variables re-eliminated, relinearised)
        self.relinearize_threshold = float(relinearize_threshold)
        #: index of the yaw bias in a keyframe's vector (-1: none) and its own relinearisation threshold (rad)
        self.bias_index, self.bias_threshold = int(bias_index), float(bias_threshold)
        self.robust = False  #: a detection factor has a robust kernel
        self.n_relinearized = 0  #: detection factors relinearised (iSAM2)
        self._theta: dict[int, np.ndarray] = {}  #: iSAM2: linearisation point of each variable
        self._lm: dict[int, list] = {}  #: iSAM2: variable -> records of its detection factors
        self._pending: list = []  #: iSAM2: (position in the new factors, record) of the detection factors not yet in
        if kind == "isam2":
            p = gtsam.ISAM2Params()
            p.setRelinearizeThreshold(relinearize_threshold)
            p.relinearizeSkip = relinearize_skip
            p.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(wildfire))
            p.setFactorization("QR")  # the tightly known calibration states make the Hessian ill-conditioned
            p.enableRelinearization = False  # every factor it holds is linear; detection factors: relinearised here
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
        else:
            self._theta[key] = x

    def add_factor(self, f) -> None:
        self._new_f.add(f)
        if self.kind == "batch":
            self._all_f.add(f)
        self.n_factors += 1

    def add_landmark_factor(self, keys: tuple[int, int], make, robust: bool = False) -> None:
        """A detection factor on ``keys``; ``make(linearize_at=None)`` builds it (see the module docstring);
        ``robust``: it has a robust kernel (its weight is then recomputed at the final estimate, :meth:`solve`)."""
        self.robust = self.robust or bool(robust)
        if self.kind == "batch":
            self.add_factor(make())
            return
        missing = [k for k in keys if k not in self._theta]
        if missing:
            raise SlamError(f"A detection factor of the factor-graph backend refers to variables the graph does not "
                            f"have: {[gtsam.DefaultKeyFormatter(k) for k in missing]}.")
        rec = {"keys": tuple(keys), "make": make, "index": None}
        self._pending.append((self._new_f.size(), rec))
        self.add_factor(make(linearize_at=[self._theta[k] for k in keys]))
        for k in keys:
            self._lm.setdefault(k, []).append(rec)

    def _relinearize(self, keys, estimate=None, threshold: float | None = None) -> int:
        """Relinearise the detection factors on those of ``keys`` whose estimate (``estimate``: a ``Values``;
        default iSAM2's current one) moved more than ``threshold`` (default ``relinearize_threshold``) from their
        linearisation point, or, for a keyframe, whose yaw bias moved more than ``bias_threshold`` (or ``threshold``
        when smaller)."""
        thr = self.relinearize_threshold if threshold is None else threshold
        bthr = self.bias_threshold if threshold is None else min(threshold, self.bias_threshold)
        moved = []
        for k in keys:
            if k not in self._lm:
                continue
            x = np.asarray(estimate.atVector(k) if estimate is not None else
                           self._gtsam("the iSAM2 estimate", self.isam.calculateEstimateVector, k))
            dx = np.abs(x - self._theta[k])
            if dx.max() > thr or (self.bias_index >= 0 and gtsam.Symbol(k).chr() == ord("x")
                                  and dx[self.bias_index] > bthr):
                moved.append((k, x))
        if not moved:
            return 0
        recs = {id(r): r for k, x in moved for r in self._lm[k]}
        for k, x in moved:
            self._theta[k] = x
        graph, remove = gtsam.NonlinearFactorGraph(), []
        for r in recs.values():
            graph.add(r["make"](linearize_at=[self._theta[k] for k in r["keys"]]))
            remove.append(r["index"])
        res = self._gtsam("an iSAM2 relinearisation", self.isam.update, graph, gtsam.Values(), remove)
        for r, i in zip(recs.values(), res.getNewFactorsIndices()):
            r["index"] = int(i)
        self.n_relinearized += len(recs)
        self._best = None
        return len(recs)

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
        self.last_result = res = self._gtsam("an iSAM2 update", self.isam.update, self._new_f, self._new_v)
        self._new_f, self._new_v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self._best = None
        if self._pending:
            idx = res.getNewFactorsIndices()
            for pos, r in self._pending:
                r["index"] = int(idx[pos])
            keys = {k for _, r in self._pending for k in r["keys"]}
            self._pending = []
            self._relinearize(sorted(keys))
        self.update_s.append(time.perf_counter() - t0)

    # ------------------------------------------------------------------ solving and reading
    def solve(self, max_iterations: int = 50) -> None:
        """Final estimate: iSAM2 (extra relinearisation rounds, then a full back-substitution) or batch LM."""
        if self.kind == "isam2":
            self.flush()
            # relinearisation rounds over every variable; with a robust kernel every detection factor that moved at all
            # (its weight is that of its linearisation point: reweighted at the final estimate, as batch LM does)
            for _ in range(3):
                self.result = self._gtsam("the iSAM2 estimate", self.isam.calculateBestEstimate)
                if not self._relinearize(sorted(self._lm), self.result, 1e-6 if self.robust else None):
                    break
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
