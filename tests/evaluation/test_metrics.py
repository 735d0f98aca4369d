"""Consistency metrics against truth (``semslam/evaluation/metrics.py``): the ANEES band, the trajectory NEES
fraction."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from semslam.evaluation.metrics import anees, chi2_band


def test_anees_band_is_closed_at_both_ends():
    """Catches an open band (``>`` for ``>=`` or ``<`` for ``<=``) in the ANEES fraction: epochs whose ANEES is
    exactly the lower or the upper limit of the 95 % band are inside it. One run, so ANEES = the NEES itself; the
    limits are ``chi2_band(3, 1)`` (checked against scipy in test_oracle_metrics), ~``chi2.ppf(0.025 / 0.975, 3)``."""
    lo, hi = chi2_band(3, 1)
    assert lo == pytest.approx(chi2.ppf(0.025, 3), rel=1e-12) and hi == pytest.approx(chi2.ppf(0.975, 3), rel=1e-12)
    runs = np.array([[lo, hi, 0.5 * (lo + hi), np.nextafter(lo, 0.0), np.nextafter(hi, np.inf)]])
    out = anees(runs, dof=3)
    assert out["band"][0] == lo and out["band"][1] == hi
    assert out["fraction_in_band"] == pytest.approx(3 / 5, abs=0)


def _epochs_with_nees(values):
    """Errors and covariances whose per-epoch position NEES is exactly ``values`` (float equality): error
    (1, 0, 0) and covariance diag(p, 1, 1) give NEES = 1 / p; p is nudged by ulps until that holds."""
    from semslam.evaluation.metrics import nees

    errs, covs = [], []
    for v in values:
        p = 1.0 / v
        for _ in range(200):
            got = nees(np.array([[1.0, 0.0, 0.0]]), np.diag([p, 1.0, 1.0])[None])[0]
            if got == v:
                break
            p = np.nextafter(p, np.inf if got > v else 0.0)
        assert got == v
        errs.append([1.0, 0.0, 0.0])
        covs.append(np.diag([p, 1.0, 1.0]))
    return np.array(errs), np.array(covs)


def test_trajectory_nees_fraction_uses_the_closed_3_dof_interval():
    """Catches a per-epoch 95 % interval with the wrong degrees of freedom (the position NEES has 3: the limits
    are ``chi2.ppf(0.025, 3)`` = 0.2158 and ``chi2.ppf(0.975, 3)`` = 9.348, not those of 4 dof, 0.4844 and 11.14)
    and an open interval (epochs exactly on a limit are inside)."""
    from semslam.evaluation.metrics import trajectory_metrics

    lo, hi = chi2.ppf(0.025, 3), chi2.ppf(0.975, 3)
    vals = [lo, hi, 0.3, 10.0, 3.0, np.nextafter(lo, 0.0), np.nextafter(hi, np.inf), 0.1]
    inside = [True, True, True, False, True, False, False, False]
    err, covs = _epochs_with_nees(vals)
    out = trajectory_metrics(err, np.zeros_like(err), covs)
    assert out["nees_position_fraction_in_95"] == pytest.approx(sum(inside) / len(inside), abs=0)
    assert out["nees_position_mean"] == pytest.approx(np.mean(vals), rel=1e-12)
