"""Accuracy and consistency metrics of a run against ground truth (NumPy only).

* ATE: RMSE of the estimated vehicle position against the truth at the history stamps (no alignment:
  the world frame is fixed by the initial state).
* NEES ``e^T P^-1 e`` of the vehicle position (3 dof) per epoch; for one run, the per-epoch 95 % interval
  ``[chi2_0.025(3), chi2_0.975(3)]``; over N Monte-Carlo runs, ANEES against
  ``[chi2_0.025(3N)/N, chi2_0.975(3N)/N]`` (Bar-Shalom, Li, Kirubarajan 2001).
"""

from __future__ import annotations

import numpy as np

from ..slam.consistency import chi2_band


def nees(errors: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """Per-epoch ``e_k^T P_k^-1 e_k`` for ``errors`` (K, d) and ``covs`` (K, d, d) (solves, no inverse)."""
    sol = np.linalg.solve(covs, errors[..., None])[..., 0]
    return np.einsum("kd,kd->k", errors, sol)


def trajectory_metrics(est_m: np.ndarray, truth_m: np.ndarray, covs: np.ndarray) -> dict:
    """ATE RMSE, final and max position error, 3-sigma figures and position NEES of one run."""
    err = est_m - truth_m
    dist = np.linalg.norm(err, axis=1)
    e = nees(err, covs)
    from scipy.stats import chi2

    lo, hi = chi2.ppf(0.025, 3), chi2.ppf(0.975, 3)
    sigma3 = 3.0 * np.sqrt(np.trace(covs, axis1=1, axis2=2))
    band = chi2_band(3, len(e))
    return {
        "ate_rmse_m": float(np.sqrt(np.mean(dist**2))),
        "final_position_error_m": float(dist[-1]),
        "max_position_error_m": float(dist.max()),
        "final_3sigma_m": float(sigma3[-1]),
        "max_3sigma_m": float(sigma3.max()),
        "nees_position_mean": float(e.mean()),
        "nees_position_band_of_mean": list(band),
        "nees_position_fraction_in_95": float(np.mean((e >= lo) & (e <= hi))),
        "fraction_within_3sigma": float(np.mean(np.abs(err) <= 3.0 * np.sqrt(np.diagonal(covs, axis1=1, axis2=2)))),
    }


def anees(nees_runs: np.ndarray, dof: int = 3) -> dict:
    """ANEES over Monte-Carlo runs: ``nees_runs`` (N, K). Fraction of epochs inside the 95 % band."""
    n = nees_runs.shape[0]
    a = nees_runs.mean(axis=0)
    lo, hi = chi2_band(dof, n)
    return {"anees": a, "band": (lo, hi), "fraction_in_band": float(np.mean((a >= lo) & (a <= hi))),
            "anees_mean": float(a.mean())}
