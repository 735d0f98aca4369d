"""The filter's own consistency summary (``semslam/slam/consistency.py``): the NIS summary per update type."""

from __future__ import annotations

import pytest
from scipy.stats import chi2

from semslam.slam.consistency import nis_summary


def test_nis_summary_skips_an_empty_type_and_keeps_the_others():
    """Catches ``break`` for ``continue`` on an update type without values: the types after it must still be
    summarised (mean and band of mean of n chi2(dof), from scipy)."""
    out = nis_summary({"empty": ([], 3), "dvl": ([1.0, 2.0, 4.5], 3), "depth": ([0.5], 1)})
    assert set(out) == {"dvl", "depth"}
    assert out["dvl"]["n"] == 3 and out["dvl"]["dof"] == 3 and out["dvl"]["mean"] == pytest.approx(2.5)
    assert out["dvl"]["band"][0] == pytest.approx(chi2.ppf(0.025, 9) / 3, rel=1e-12)
    assert out["depth"]["band"][1] == pytest.approx(chi2.ppf(0.975, 1), rel=1e-12)
