"""The result object every registration stage returns."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import RigidTransform


@dataclass(frozen=True, eq=False)
class RegistrationResult:
    """Outcome of aligning a source cloud onto a target cloud.

    Parameters
    ----------
    T_target_source : RigidTransform
        Maps source-frame points into the target frame: ``p_target = T_target_source @ p_source``.
    fitness : float
        Inlier fraction: share of the source points whose nearest target point (after alignment) is
        closer than the stage's maximum correspondence distance, in [0, 1].
    inlier_rmse_m : float
        Root-mean-square nearest-neighbour distance over those inliers (metres); NaN without inliers.
    n_iterations : int
        Iterations run (RANSAC hypotheses drawn, or ICP iterations).
    converged : bool
        The coarse stage found a hypothesis passing the inlier-fraction threshold, or ICP met its
        convergence criterion before the iteration cap.
    timings_ms : dict of str to float
        Wall-clock time of each stage, in milliseconds.
    n_inliers : int
        Number of inlier source points.
    max_correspondence_m : float
        Distance used to count inliers (metres).
    method : str
        Which stage produced the transform (``"prerejective"``, ``"icp"``, ``"plane_icp"`` ...).
    extras : dict
        Stage-specific diagnostics (hypotheses scored, pre-rejected ...).
    """

    T_target_source: RigidTransform
    fitness: float
    inlier_rmse_m: float
    n_iterations: int
    converged: bool
    timings_ms: dict = field(default_factory=dict)
    n_inliers: int = 0
    max_correspondence_m: float = float("inf")
    method: str = ""
    extras: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-friendly form."""
        return {
            "T_target_source": self.T_target_source.to_dict(),
            "fitness": float(self.fitness),
            "inlier_rmse_m": float(self.inlier_rmse_m),
            "n_iterations": int(self.n_iterations),
            "converged": bool(self.converged),
            "n_inliers": int(self.n_inliers),
            "max_correspondence_m": float(self.max_correspondence_m),
            "method": self.method,
            "timings_ms": {k: float(v) for k, v in self.timings_ms.items()},
            **({"extras": self.extras} if self.extras else {}),
        }


def inlier_statistics(source_points_target: np.ndarray, target_tree, max_correspondence_m: float,
                      ) -> tuple[float, float, int]:
    """Fitness (inlier fraction), inlier RMSE (m) and inlier count of aligned source points.

    ``source_points_target`` (N, 3) are the source points already mapped into the target frame;
    ``target_tree`` is a ``scipy.spatial.cKDTree`` of the target points.
    """
    n = len(source_points_target)
    if n == 0:
        return 0.0, float("nan"), 0
    bound = max_correspondence_m if np.isfinite(max_correspondence_m) else np.inf
    d, _ = target_tree.query(source_points_target, k=1, distance_upper_bound=bound)
    return _inlier_statistics_of_distances(d, max_correspondence_m)


def _inlier_statistics_of_distances(d: np.ndarray, max_correspondence_m: float) -> tuple[float, float, int]:
    """:func:`inlier_statistics` from the nearest-neighbour distances (N,) (inf beyond the bound), N > 0."""
    n = len(d)
    ok = d <= max_correspondence_m
    n_in = int(np.count_nonzero(ok))
    rmse = float(np.sqrt(np.mean(d[ok] ** 2))) if n_in else float("nan")
    return n_in / n, rmse, n_in
