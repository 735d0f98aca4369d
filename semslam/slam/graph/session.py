"""``GraphSession``: the streaming :class:`~semslam.slam.session.SlamSession` interface on a GTSAM factor graph.

Backends: ``isam2`` (incremental smoothing: :meth:`GraphSession.estimate` is the graph's optimum given everything
so far, at any time) and ``batch`` (Levenberg-Marquardt over the whole dive at :meth:`GraphSession.finish`; online it
has only the front-end filter's estimate).

The graph models the EKF's problem (see :mod:`~semslam.slam.graph.factors`): keyframes at every history epoch
(``config.output.history_rate_hz``) and at every stamp with detections; the predictions, DVL and depth updates
between them are eliminated exactly into one factor per segment (:mod:`~semslam.slam.graph.segment`); landmark
factors are the filter's measurement model, relinearised. Decisions (gates, association, consensus creation) are
the front-end filter's (:mod:`~semslam.slam.graph.frontend`): one association module for every backend.

Result (:class:`~semslam.slam.results.SlamResult`): ``position_ned_m`` / ``position_cov_m2`` are the online
estimates at each epoch (iSAM2's when the epoch was the present; the front-end filter's for ``batch``);
``smoothed_*`` the graph's final estimate of every epoch with its marginal; ``landmarks`` the graph's final map with
marginal covariances; ``metrics["graph"]`` the backend's figures. Documented behaviour: a landmark is created only by
consensus (``consensus_min_observations`` agreeing detections): an object seen once never enters the graph; a dive
without detections is dead reckoning (the graph is then the smoother of mode ``dr``); a DVL gap only grows the
segment's process noise.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ...detection import Detection
from ...errors import SlamError
from ..results import LandmarkEstimate, SlamEstimate, SlamResult
from ..session import SlamSession
from .backend import BACKENDS, GraphBackend
from .frontend import FrontEkf, GraphMapper


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


class GraphSession(SlamSession):
    """:class:`SlamSession`'s interface and outputs on a factor graph (see the module docstring).

    Parameters are :class:`SlamSession`'s, plus ``backend`` (``isam2`` or ``batch``) and ``huber_k`` (Huber threshold,
    in sigmas of the whitened residual, of the detection factors; None: Gaussian).
    """

    def __init__(self, vehicle, *, backend: str = "isam2", huber_k: float | None = None, **kw) -> None:
        if backend not in BACKENDS:
            raise SlamError(
                f"The 'backend' argument of GraphSession must be one of {BACKENDS}. Got {backend!r} instead."
            )
        if huber_k is not None and (isinstance(huber_k, bool) or not isinstance(huber_k, (int, float))
                                    or not np.isfinite(huber_k) or huber_k <= 0):
            raise SlamError(
                f"The 'huber_k' argument of GraphSession must be a number > 0 or None. Got {huber_k!r} instead."
            )
        super().__init__(vehicle, **kw)
        self.backend_name, self.huber_k = backend, huber_k
        self.graph: GraphBackend | None = None
        self._online: dict[str, list] = {k: [] for k in ("p", "Pp", "v", "Pv", "b")}
        self._hist_keys: list[int] = []
        self._wall = 0.0

    # ------------------------------------------------------------------ set-up (SlamSession's factory hooks)
    def _make_filter(self, x0_position, v0_body, P0, **kw) -> FrontEkf:
        """The front-end filter: the same EKF, mirroring its operations into the graph."""
        ekf = FrontEkf(x0_position, v0_body, P0, **kw)
        ekf.huber_k, ekf.orientation_innovation = self.huber_k, self.cfg.gating.orientation_innovation
        ekf.backend = self.graph = GraphBackend(self.backend_name, ekf.n_v, bias_index=ekf.i_yaw)
        return ekf

    def _make_recorder(self) -> None:
        return None  # the graph is the smoother

    def _filter_ready(self, ekf: FrontEkf) -> None:
        self.graph.start(self.t, ekf.xa[:ekf.n_v].copy(), ekf.Paa[:ekf.n_v, :ekf.n_v].copy())

    def _make_mapper(self, ekf: FrontEkf) -> GraphMapper:
        return GraphMapper(ekf, self.cfg, self.mode, self.symmetries, self.vehicle.T_vehicle_scanner, self._log,
                           records=self.log)

    # ------------------------------------------------------------------ messages
    def add_detections(self, stamp_s, detections) -> None:
        for k, d in enumerate(list(detections)):
            if isinstance(d, Detection):
                C = np.asarray(d.covariance_6x6, dtype=float)
                ok = C.shape == (6, 6) and np.isfinite(C).all()
                w = np.linalg.eigvalsh(0.5 * (C + C.T)) if ok else np.array([np.nan])
                if not ok or w.min() < -1e-12 * max(abs(w.max()), 1.0):
                    raise SlamError(f"The 'covariance_6x6' of detection {k} given to GraphSession.add_detections at "
                                    f"{stamp_s!r} s must be a finite positive semi-definite 6x6 matrix. Got smallest "
                                    f"eigenvalue {w.min():.3g} instead.")
        t0 = time.perf_counter()
        super().add_detections(stamp_s, detections)
        self._wall += time.perf_counter() - t0

    def _drain(self, final: bool) -> None:
        t0 = time.perf_counter()
        super()._drain(final)
        if self.graph is not None:
            self.graph.flush()
        self._wall += time.perf_counter() - t0

    def _record(self, t: float) -> None:
        super()._record(t)
        ekf, g = self.ekf, self.graph
        key = g.keyframe(t, ekf.xa[:ekf.n_v])
        self._hist_keys.append(key)
        if g.kind == "isam2":
            g.flush()
            x, P = g.vector(key), g.cov(key)
        else:
            x, P = ekf.xa[:ekf.n_v].copy(), ekf.Paa[:ekf.n_v, :ekf.n_v].copy()
        self._store(self._online, x, P)

    def _store(self, H: dict, x: np.ndarray, P: np.ndarray) -> None:
        ekf = self.ekf
        H["p"].append(x[0:3].copy())
        H["Pp"].append(P[0:3, 0:3].copy())
        H["v"].append(x[3:6].copy())
        H["Pv"].append(P[3:6, 3:6].copy())
        H["b"].append(float(x[ekf.i_yaw]) if ekf.yaw_bias else 0.0)

    # ------------------------------------------------------------------ outputs
    def _graph_landmarks(self, final: bool) -> list[LandmarkEstimate]:
        from .factors import L

        out = []
        for j, lm in enumerate(self.ekf.landmarks):
            x = self.graph.vector(L(j), final).copy()
            x[3:6] = _wrap(x[3:6])
            out.append(LandmarkEstimate(j, lm.label, x, self.graph.cov(L(j), final), lm.first_seen_s, lm.last_seen_s,
                                        lm.n_updates, name=lm.name))
        return out

    def estimate(self) -> SlamEstimate:
        """iSAM2: the graph's current optimum (a keyframe is made at the present); batch: the front-end filter's."""
        if self.ekf is None or self.graph.kind == "batch":
            return super().estimate()
        ekf, g = self.ekf, self.graph
        key = g.keyframe(self.t, ekf.xa[:ekf.n_v])
        g.flush()
        g.best()  # every variable exact (O(size of the graph): estimate() is a query, not the per-update path)
        x, P = g.vector(key), g.cov(key)
        return SlamEstimate(self.t, x[0:3].copy(), P[0:3, 0:3].copy(), x[3:6].copy(), P[3:6, 3:6].copy(),
                            float(x[ekf.i_yaw]) if ekf.yaw_bias else 0.0, self._graph_landmarks(False))

    def _result(self) -> SlamResult:
        base = super()._result()
        ekf, g = self.ekf, self.graph
        t0 = time.perf_counter()
        g.keyframe(self.t, ekf.xa[:ekf.n_v])
        g.close_unary()
        g.solve()
        sm: dict[str, list] = {k: [] for k in ("p", "Pp", "v", "Pv", "b")}
        for key in self._hist_keys:
            self._store(sm, g.vector(key, True), g.cov(key, True))
        landmarks = self._graph_landmarks(True)
        self._wall += time.perf_counter() - t0
        on = self._online
        K = len(self._hist_keys)
        ups = np.asarray(g.update_s) if g.update_s else np.zeros(1)
        dur = base.metrics.get("duration_s", 0.0)
        metrics = dict(
            base.metrics,
            backend=self.backend_name,
            graph={
                "backend": self.backend_name,
                "n_keyframes": len(g.kf_t),
                "n_factors": g.n_factors,
                "n_landmarks": g.n_landmarks,
                "n_updates": int(len(g.update_s)),
                "batch_iterations": g.iterations,
                "detection_factors_relinearized": g.n_relinearized,
                "update_mean_s": float(ups.mean()),
                "update_max_s": float(ups.max()),
                "wall_s": self._wall,
                "real_time_factor": dur / self._wall if self._wall > 0 else float("inf"),
                "huber_k": self.huber_k,
            },
        )
        metrics["smoother"] = {"status": f"graph ({self.backend_name})"}  # evaluate_run adds its ATE and NEES
        arr = lambda H, k, s: np.asarray(H[k]).reshape(s)  # noqa: E731
        return replace(base, position_ned_m=arr(on, "p", (K, 3)), position_cov_m2=arr(on, "Pp", (K, 3, 3)),
                       velocity_body_mps=arr(on, "v", (K, 3)), velocity_cov=arr(on, "Pv", (K, 3, 3)),
                       yaw_bias_rad=np.asarray(on["b"]), landmarks=landmarks, metrics=metrics,
                       smoothed_position_ned_m=arr(sm, "p", (K, 3)), smoothed_position_cov_m2=arr(sm, "Pp", (K, 3, 3)),
                       smoothed_velocity_body_mps=arr(sm, "v", (K, 3)))
