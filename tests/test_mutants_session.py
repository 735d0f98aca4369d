"""Tests that kill surviving mutants of ``semslam/slam/session.py`` (benchmarks/mutation.py)."""

from __future__ import annotations

import numpy as np

from semslam.dataset.vehicle import VehicleDescription
from semslam.slam.config import OutputConfig, SlamConfig
from semslam.slam.session import SlamSession


def _feed(session, n=20):
    for k in range(n):
        t = 0.1 * k
        session.add_attitude(t, [0.0, 0.0, 0.3])
        session.add_dvl(t + 0.05, [0.3, 0.0, 0.0])
        session.add_depth(t + 0.05, 2.0)


def test_finish_when_the_smoother_ran_out_of_budget():
    """Catches a finish step that reads the smoothed states when there are none (``sm is None and len(sm.x)``
    in the consistency check): with a smoother budget too small for even one covariance the run still
    finishes, without a smoothed trajectory, and says why."""
    cfg = SlamConfig(output=OutputConfig(smoother_max_mb=1e-6))
    s = SlamSession(VehicleDescription.girona500(), mode="dr", config=cfg)
    _feed(s)
    res = s.finish()
    assert res.smoothed_position_ned_m is None
    assert res.metrics["smoother"]["status"].startswith("skipped")
    assert len(res.position_ned_m) == len(res.stamps_s) > 0
    ok = SlamSession(VehicleDescription.girona500(), mode="dr", config=SlamConfig())
    _feed(ok)
    full = ok.finish()
    assert full.smoothed_position_ned_m.shape == full.position_ned_m.shape
    assert np.isfinite(full.smoothed_position_ned_m).all()
