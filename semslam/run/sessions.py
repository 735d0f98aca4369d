"""The filter sessions of a run: :func:`make_session` (the EKF or a GTSAM graph) and :func:`with_start` (the run's
start in its result's metrics), used by the streaming runner (:mod:`semslam.run.runner`)."""

from __future__ import annotations

from ..modes import BACKENDS
from .._validation import check_choice
from ..slam.config import SlamConfig
from ..slam.initial import InitialState
from ..slam.results import SlamResult
from ..slam.session import SlamSession

__all__ = ["BACKENDS", "make_session", "with_start"]


def make_session(vehicle, start: InitialState, *, mode: str, config: SlamConfig, symmetries=None,
                 backend: str = "ekf", huber_k: float | None = None):
    """A :class:`SlamSession` (or, for ``backend`` isam2/batch, a GTSAM :class:`GraphSession`) starting at
    ``start``."""
    check_choice("backend", backend, BACKENDS, caller="make_session")
    kw = dict(mode=mode, config=config, symmetries=symmetries, start=start)
    if backend == "ekf":
        return SlamSession(vehicle, **kw)
    from ..slam.graph import GraphSession  # lazily: GTSAM is imported only for the graph backends

    return GraphSession(vehicle, backend=backend, huber_k=huber_k, **kw)


def with_start(result: SlamResult, start: InitialState) -> SlamResult:
    """``result`` with its start (stamp, position, frame, sources) in its metrics."""
    from dataclasses import replace

    return replace(result, metrics={**result.metrics, "start": start.as_dict()})


