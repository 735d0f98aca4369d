"""Consistency statistics the filter reports about itself, without any truth: the chi-square band of a mean of
NIS (or NEES) values and the NIS summary per update type, ``mean`` against ``[chi2_0.025(m K)/K,
chi2_0.975(m K)/K]`` (Bar-Shalom, Li, Kirubarajan 2001)."""

from __future__ import annotations

import numpy as np


def chi2_band(dof: int, n: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided band of the mean of ``n`` independent chi-square(dof) variables."""
    a = (1.0 - probability) / 2.0
    from scipy.stats import chi2  # lazily: scipy.stats costs ~1 s to import

    return float(chi2.ppf(a, dof * n) / n), float(chi2.ppf(1.0 - a, dof * n) / n)


def nis_summary(nis_by_type: dict[str, tuple[list[float], int]]) -> dict:
    """Mean NIS per update type with its chi-square band: ``{type: (values, dof)}``."""
    out = {}
    for kind, (values, dof) in nis_by_type.items():
        v = np.asarray(values, dtype=float)
        if len(v) == 0:
            continue
        out[kind] = {"n": int(len(v)), "dof": int(dof), "mean": float(v.mean()), "band": list(chi2_band(dof, len(v)))}
    return out
